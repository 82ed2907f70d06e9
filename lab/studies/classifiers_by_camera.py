"""Two upright classifier graphs compared, view by view, on a run's validation views, each view
rule (clean or by a depth camera) apart: each graph fused with the classifier for any
orientation as served (``export/classifier_export.py: score_graph``), one view per call.

    python -m lab.studies.classifiers_by_camera itnet/models/classifier_upright.onnx \
        /tmp/classifier_upright.onnx --run runs/cls_upright_sensor

The run's views are one block per view rule of its config (``model/classify/data.py:
fixed_views``). Prints, per rule, each graph's top-1 and the second's paired gain over the
first with its standard error. A graph is kept where the camera views gain and the clean ones
lose no more than a standard error.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from itnet.metrics import paired_accuracy
from itnet.pose.recognition import mean_log_probability
from itnet.pose.runtime import LoadedClassifier, load_any


def fused_correct(
    graph: LoadedClassifier,
    beside: LoadedClassifier,
    x: np.ndarray,
    free: np.ndarray,
    y: np.ndarray,
) -> np.ndarray:
    """(V,) 1.0 where the graph on the levelled view, fused with ``beside`` on the unlevelled
    one, names the view's class."""
    upright = np.concatenate(
        [graph.probabilities(x[i : i + 1, : graph.card.points]) for i in range(len(x))]
    )
    other = np.concatenate(
        [beside.probabilities(free[i : i + 1, : beside.card.points]) for i in range(len(x))]
    )
    return (mean_log_probability([other, upright]).argmax(1) == y).astype(float)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path)
    parser.add_argument("second", type=Path)
    parser.add_argument("--run", type=Path, required=True, help="a run folder: its val views")
    parser.add_argument("--beside", type=Path, default=Path("itnet/models/classifier.onnx"))
    parser.add_argument("--out", type=Path, help="write the table as JSON here")
    args = parser.parse_args()

    from itnet.model.classify.train import ClassifyConfig, run_splits, run_views

    config = ClassifyConfig.model_validate_json((args.run / "config.json").read_text())
    _, splits = run_splits(config)
    x, y = run_views(config, splits, "val")
    free, labels = run_views(config.model_copy(update={"upright": None}), splits, "val")
    assert (labels == y).all()
    beside = load_any(args.beside, warm_up=False)
    graphs = [load_any(p, warm_up=False) for p in (args.first, args.second)]
    assert isinstance(beside, LoadedClassifier)
    assert all(isinstance(g, LoadedClassifier) and g.card.upright for g in graphs)
    right = [fused_correct(g, beside, x, free, y) for g in graphs]  # type: ignore[arg-type]

    rules = config.views or ["occluded", "paper"]
    block = len(y) // len(rules)
    rows = {}
    print(f"{'view rule':28s} {'views':>5s} {'first':>7s} {'second':>7s} {'gain':>14s}")
    for k, rule in enumerate([*rules, "all"]):
        part = slice(0, len(y)) if rule == "all" else slice(k * block, (k + 1) * block)
        a, b = right[0][part], right[1][part]
        rows[rule] = {"first": 100 * round(float(a.mean()), 3), **paired_accuracy(b, a)}
        print(
            f"{rule:28s} {len(a):5d} {100 * a.mean():6.1f}% {100 * b.mean():6.1f}% "
            f"{rows[rule]['gain']:+6.1f} ± {rows[rule]['gain_stderr']:.1f}"
        )
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
