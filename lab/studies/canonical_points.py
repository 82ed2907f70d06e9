"""How many points does the classifier's canonicaliser need? The shipped classifier's weights
exported with the IT-Net canonicaliser on the first K of the 256 input points
(``ClassifierCard.canonical_points``, ``itnet classify-export --canonical-points K``), each K
against all 256 on the same validation views, paired, and the graph's time (interleaved).

    python -m lab.studies.canonical_points --ks 32 64 96 128 [--split val] [--out X.json]

Two view sets of the split, both fed in random order as served: the run's fixed views
(``run_views``, resampled to 256, ``--shuffles`` orders each) and served-style scans
(``--views`` a shape, alternately occluded and the paper's, capped at 256 as the service caps a
request). The choice is made on ``val``; ``test`` is for the choice, once.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def served_views(config, splits, split: str, views: int) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """Scans of the split's shapes as a request brings them: (V, 256, 3) normalised, in random
    order (a smaller scan padded by repeats, which do not change the max-pool), labels (V,)."""
    from itnet.model.classify.data import view_configs
    from itnet.model.scanner import scan_of
    from itnet.preprocess import estimate_normalization, resample, shuffled_subset

    rng = np.random.default_rng(2024 if split == "test" else 7)
    configs = view_configs()
    xs, ys = [], []
    for shape, label in zip(splits[split].shapes, splits[split].labels, strict=True):
        for v in range(views):
            cloud, _ = scan_of(shape, rng, configs[v % len(configs)])
            seen = shuffled_subset(estimate_normalization(cloud).apply(cloud), config.points, rng)
            xs.append(resample(seen, config.points, rng))  # repeats after the shuffled points
            ys.append(int(label))
    return np.stack(xs).astype(np.float32), np.asarray(ys)


def graph_ms(graphs: dict[str, object], x: np.ndarray, rounds: int = 6, runs: int = 150) -> dict:
    """Median and 90th percentile of one call (one view) per graph, interleaved in rounds."""
    times: dict[str, list[float]] = {k: [] for k in graphs}
    for _ in range(rounds):
        for k, g in graphs.items():
            for _ in range(20):
                g.probabilities(x)  # type: ignore[attr-defined]
            for _ in range(runs):
                start = time.perf_counter()
                g.probabilities(x)  # type: ignore[attr-defined]
                times[k].append((time.perf_counter() - start) * 1e3)
    return {
        k: {
            "median_ms": round(float(np.median(t)), 3),
            "p90_ms": round(float(np.percentile(t, 90)), 3),
        }
        for k, t in times.items()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", type=Path, default=ROOT / "lab/weights/classifier.pt")
    parser.add_argument("--ks", type=int, nargs="+", default=[32, 64, 96, 128])
    parser.add_argument("--split", choices=["val", "test"], default="val")
    parser.add_argument("--views", type=int, default=8, help="served-style scans a shape")
    parser.add_argument("--shuffles", type=int, default=3, help="orders of each fixed view")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    from itnet.export.classifier_export import export_classifier
    from itnet.metrics import paired_accuracy
    from itnet.model.classify.data import shuffled_views
    from itnet.model.classify.train import (
        ClassifyConfig,
        load_classifier,
        run_of_checkpoint,
        run_splits,
        run_views,
    )
    from itnet.model_card import ClassifierCard
    from itnet.pose.runtime import LoadedClassifier, load_any

    with tempfile.TemporaryDirectory() as tmp:
        run = run_of_checkpoint(args.checkpoint, Path(tmp) / "run")
        config = ClassifyConfig.model_validate_json((run / "config.json").read_text())
        classes, splits = run_splits(config)
        net, _ = load_classifier(run / "best.pt")
        graphs: dict[str, LoadedClassifier] = {}
        for k in [None, *args.ks]:
            card = ClassifierCard(classes=classes, points=config.points, canonical_points=k)
            graph = load_any(export_classifier(net, card, Path(tmp) / f"k{k}.onnx"), threads=2)
            assert isinstance(graph, LoadedClassifier)
            graphs["all" if k is None else str(k)] = graph
        fixed, fixed_y = run_views(config, splits, args.split)
        sets = {
            "fixed": (
                np.concatenate(
                    [shuffled_views(fixed, np.random.default_rng(s)) for s in range(args.shuffles)]
                ),
                np.tile(fixed_y, args.shuffles),
            ),
            "served": served_views(config, splits, args.split, args.views),
        }
        results: dict[str, dict] = {}
        for name, (x, y) in sets.items():
            hits = {}
            for k, graph in graphs.items():
                probs = np.concatenate([graph.probabilities(x[i : i + 1]) for i in range(len(x))])
                hits[k] = probs.argmax(1) == y
            results[name] = {k: paired_accuracy(h, hits["all"]) for k, h in hits.items()}
            print(f"{name} ({len(y)} {args.split} views):", flush=True)
            for k, r in results[name].items():
                print(f"  K={k}: {r}", flush=True)
        timing = graph_ms(graphs, sets["served"][0][:1])
        for k, t in timing.items():
            print(f"  K={k}: graph {t}", flush=True)
    report = {
        "checkpoint": str(args.checkpoint),
        "split": args.split,
        "points": config.points,
        "accuracy": results,
        "graph_time": timing,
        "machine": f"{platform.machine()} {os.cpu_count()} cores",
    }
    if args.out is not None:
        args.out.write_text(json.dumps(report, indent=1))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
