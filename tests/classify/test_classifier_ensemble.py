"""benchmarks/classifier_ensemble.py: two classifiers' probabilities fused in the log domain, each
member and the fusion scored on the trainer's fixed views."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from modelnet_tree import write_modelnet_tree

from benchmarks.classifier_ensemble import main
from itnet.model.classify.train import ClassifyConfig, train
from itnet.pose.recognition import mean_log_probability as fuse


def test_fusion_is_the_geometric_mean_of_the_members() -> None:
    confident = np.array([[0.6, 0.4], [0.9, 0.1]])
    other = np.array([[0.1, 0.9], [0.6, 0.4]])
    assert fuse([confident, confident]).argmax(1).tolist() == [0, 0]
    # 0.6 * 0.1 < 0.4 * 0.9: the second class; 0.9 * 0.6 > 0.1 * 0.4: the first
    assert fuse([confident, other]).argmax(1).tolist() == [1, 0]
    assert np.isfinite(fuse([np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])])).all()


def test_two_tiny_classifiers_are_scored_alone_and_fused(tmp_path: Path, monkeypatch) -> None:
    rng = np.random.default_rng(2)
    shapes = {
        "plate": lambda r: r.uniform(-1, 1, (300, 3)) * [1.0, 0.7, 0.05],
        "rod": lambda r: r.uniform(-1, 1, (300, 3)) * [0.08, 0.08, 1.0],
    }
    data = write_modelnet_tree(tmp_path / "data", shapes, rng, train=8, test=2)
    checkpoints = []
    for seed in (None, 1):
        out = tmp_path / f"run{seed}"
        config = ClassifyConfig(
            data=data, variant="itnet-1", out=out, cache=tmp_path / "cache", steps=10, batch=8,
            points=64, eval_every=10, widths=((16, 32, 64), (32, 16)), bf16=False, init_seed=seed,
        )  # fmt: skip
        train(config)
        checkpoints.append(str(out / "best.pt"))
    report = tmp_path / "ensemble.json"
    argv = ["classifier_ensemble", *checkpoints, "--data", str(data)]
    argv += ["--cache", str(tmp_path / "cache"), "--threads", "1", "--out", str(report)]
    monkeypatch.setattr(sys, "argv", argv)
    main()
    result = json.loads(report.read_text())
    assert result["split"] == "val" and result["views"] > 0
    assert list(result["members"]) == checkpoints
    first = result["members"][checkpoints[0]]
    assert first["gain"] == 0.0 and 0 <= first["accuracy"] <= 100
    assert result["fused"]["scans"] == result["views"] and 0 <= result["agreement"] <= 100
    # the same checkpoint twice: full agreement, and the fusion is that member
    argv[1:3] = [checkpoints[0], checkpoints[0]]
    main()
    same = json.loads(report.read_text())
    assert same["agreement"] == 100.0 and same["fused"]["gain"] == 0.0
    # more views a shape, and the transformers reading only the first points, as served
    argv += ["--views", "4", "--canonical-points", "8"]
    main()
    served = json.loads(report.read_text())
    assert served["views"] == 2 * result["views"] and served["canonical_points"] == 8
    # gains against a fused baseline: the same fusion gains nothing, and the first member alone
    # as the baseline is the default
    argv[1:3] = checkpoints
    argv += ["--baseline", *checkpoints]
    main()
    against_fusion = json.loads(report.read_text())
    assert against_fusion["baseline"] == checkpoints
    assert against_fusion["fused"]["gain"] == 0.0 and against_fusion["fused"]["gain_stderr"] == 0.0
    argv[-2:] = [checkpoints[0]]
    main()
    against_first = json.loads(report.read_text())
    del argv[-2:]
    main()
    assert against_first == json.loads(report.read_text())
