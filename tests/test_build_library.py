"""The build side called from Python, without the command line: a checkpoint exported, its card
changed, the model measured and its centre correction fitted, a tiny run trained, and the
models of a folder listed; each returns its report and refuses bad input with InputError."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from itnet.export.card_config import CardChanges
from itnet.export.export_config import ExportOptions
from itnet.model.centre_fit_config import CentreFitOptions
from itnet.model.eval_config import EvalOptions
from itnet.model.input_error import InputError
from itnet.model.train_config import TrainOptions

SHIPPED = Path(__file__).resolve().parents[1] / "itnet" / "models"


def _chair_like(rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """A seat and a back rising from its rear edge: not symmetric about up."""
    seat = rng.uniform([-0.5, -0.05, -0.5], [0.5, 0.05, 0.5], size=(n // 2, 3))
    back = rng.uniform([-0.5, 0.05, 0.4], [0.5, 0.9, 0.5], size=(n - n // 2, 3))
    return np.concatenate([seat, back]) * rng.uniform(0.8, 1.2, size=3)


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with data/chair/{train,test} and a checkpoint of the tiny network."""
    import torch
    from factory import make_tiny_net
    from modelnet_tree import write_modelnet_tree

    folder = tmp_path_factory.mktemp("build")
    write_modelnet_tree(folder / "data", {"chair": _chair_like}, np.random.default_rng(0), 12, 2)
    net = make_tiny_net()
    config = {"category": "chair", "points": 64, "iterations": 2, "batch": 8, "lr": 1e-3,
              "decay_every": 10, "bf16": False}  # fmt: skip
    state = {"model": net.state_dict(), "network": dataclasses.asdict(net.config), "step": 3,
             "config": config, "metrics": {"val_accuracy": 0.25}}  # fmt: skip
    torch.save(state, folder / "tiny.pt")
    return folder


@pytest.fixture(scope="module")
def exported(root: Path) -> Path:
    from itnet.export.checkpoint_export import export_checkpoint

    done = export_checkpoint(root / "tiny.pt", ExportOptions(out=root / "x.onnx", name="x"))
    assert done.path == root / "x.onnx" and done.size_bytes == done.path.stat().st_size
    assert done.max_diff < 1e-4
    return done.path


def test_export_writes_the_checkpoints_card(root: Path, exported: Path) -> None:
    from itnet.export.checkpoint_export import export_checkpoint
    from itnet.pose.runtime import load_model

    card = load_model(exported, warm_up=False).card
    assert (card.name, card.category, card.points, card.trained_iterations) == ("x", "chair", 64, 2)
    assert card.mirror_planes == ["x"] and card.training["steps"] == 3  # the chair's table
    assert card.training["validation"] == 0.25 and not card.requires_up
    out = root / "refused.onnx"
    with pytest.raises(InputError, match="--ensemble-report"):
        export_checkpoint(root / "tiny.pt", ExportOptions(out=out, recommended_ensemble=3))
    with pytest.raises(InputError, match="--mirror-planes"):
        export_checkpoint(root / "tiny.pt", ExportOptions(out=out, mirror_planes="y"))
    assert not out.exists()


def test_edit_card_writes_only_a_change(root: Path, exported: Path) -> None:
    from itnet.export.card_edit import edit_card
    from itnet.pose.runtime import ModelLoadError, load_model

    shown = edit_card(exported, CardChanges())
    assert shown.written is None and shown.card == load_model(exported, warm_up=False).card
    out = root / "planes.onnx"
    done = edit_card(exported, CardChanges(mirror_planes="x,z", mirror_fused=True, out=out))
    assert done.written == out and load_model(out, warm_up=False).card == done.card
    assert done.card.mirror_planes == ["x", "z"] and done.card.mirror_fused
    cleared = edit_card(out, CardChanges(mirror_planes="none"))
    assert cleared.card.mirror_planes == [] and not cleared.card.mirror_fused
    with pytest.raises(InputError, match="neither"):
        edit_card(exported, CardChanges(with_mirror=root / "on.json"))
    with pytest.raises(InputError, match="--with-verify"):
        edit_card(exported, CardChanges(verify_fused=True))
    with pytest.raises(ModelLoadError, match="classify-export"):
        edit_card(SHIPPED / "classifier.onnx", CardChanges(mirror_planes="x"))


def test_evaluate_model_writes_the_report_and_agrees_with_torch(root: Path, exported: Path) -> None:
    from itnet.model.eval_run import evaluate_model

    common = dict(data=root / "data", category="chair", views=2, iterations=2,
                  check_orientation=False, cache=root / "cache")  # fmt: skip
    done = evaluate_model(
        EvalOptions(onnx=exported, out=root / "e1", dump_scans=root / "scans", **common)
    )
    assert done.anytime.iterations == [0, 1, 2] and done.anytime.scans == 4 and done.objects == 2
    assert json.loads(done.report.read_text()) == done.summary
    assert done.summary["points"] == 64 and done.summary["source"] == str(exported)
    assert done.plot.stat().st_size > 0 and done.poses.exists()
    assert len(list(done.scans.glob("*.npy"))) == 4 and (done.scans / "labels.json").exists()
    torch_run = evaluate_model(EvalOptions(checkpoint=root / "tiny.pt", out=root / "e2", **common))
    assert np.allclose(
        torch_run.anytime.median_rotation_deg, done.anytime.median_rotation_deg, atol=0.05
    )
    with pytest.raises(InputError, match="exactly one"):
        evaluate_model(EvalOptions(out=root / "e3", **common))
    with pytest.raises(InputError, match="--scanner"):
        evaluate_model(EvalOptions(onnx=exported, scanner="nearest", **common))


def test_fit_model_centre_measures_and_writes_the_correction(root: Path, exported: Path) -> None:
    from itnet.model.centre_fit_run import fit_model_centre
    from itnet.pose.runtime import load_model

    logged: list[str] = []
    options = CentreFitOptions(data=root / "data", views=1, val_views=2, cache=root / "cache",
                               max_rotation=181.0, write=True, out=root / "fitted.onnx",
                               report=root / "centre.json")  # fmt: skip
    done = fit_model_centre(exported, options, log=logged.append)
    assert set(done.results) == set(done.viewpoint_results) == {"occluded", "paper"}
    assert done.plain_results == {} and done.served_viewpoint_results == {}  # without up
    assert len(logged) == 2 and done.evaluation.startswith("validation views, one run")
    assert json.loads(done.report.read_text())["evaluation"] == done.evaluation
    fitted = load_model(done.written, threads=1)
    assert fitted.card.centre_evaluation == done.evaluation
    assert fitted.card.centre_correction == done.correction.to_dict()
    refused = options.model_copy(update={"max_rotation": 0.001, "write": False})
    with pytest.raises(InputError, match="not accurate enough"):
        fit_model_centre(exported, refused)


@pytest.mark.train
def test_train_run_reports_its_best_checkpoint(root: Path) -> None:
    from itnet.model.train_run import train_run

    options = TrainOptions(
        data=root / "data", category="chair", out=root / "run", cache=root / "cache", steps=2,
        batch=8, points=64, iterations=2, eval_every=2, threads=1, bf16=False, compile=False,
        ema=0.0, check_orientation=False,
    )  # fmt: skip
    done = train_run(options, progress=False)
    assert done.checkpoint == root / "run" / "best.pt" and done.checkpoint.exists()
    assert done.step == 2 and 0.0 <= done.val_accuracy <= 1.0
    assert done.metrics["val_accuracy"] == done.val_accuracy
    with pytest.raises(InputError, match="--loss"):
        train_run(options.model_copy(update={"loss": "cubic", "out": root / "no"}))
    assert not (root / "no").exists()  # refused before anything is written


def test_list_models_is_the_services_listing_as_a_table(tiny_model_dir: Path) -> None:
    from itnet.model_listing import HEADER, list_models, listing_lines

    listing = list_models(tiny_model_dir)
    assert listing.folder == tiny_model_dir and [m.name for m in listing.reply.models] == ["tiny"]
    header, row, legend = listing_lines(listing)
    assert header.split() == [h for h in HEADER if h]
    assert row.split()[:9] == ["tiny", "chair", "none", "-", "-", "-", "float32", "256", "1"]
    assert row.endswith("default") and legend.startswith(f"(1 model(s) in {tiny_model_dir}; ")
