"""Does the classifier gain from several looks at one cloud? K inputs per view, their class
probabilities averaged (as log-probabilities): own random 256-point subsets of the cloud, and
optionally each turned 360/K degrees about the cloud's z axis (the canonicaliser then starts from
K different poses, as the pose ensemble's runs do), or turned with every second look also
reflected in x ('mirrored': a mirror-symmetric object's reflected view is a view of it from the
mirrored camera). Top-1 and mean class accuracy against one
look, paired, and the time of one request's batch of K through the shipped graph; with the size
prior too where the card has one (each view's size in metres, ModelNet's units read as inches,
as ``itnet classify-size-prior`` measures it).

    python -m benchmarks.classify_tta --split val              # where the choice is made
    python -m benchmarks.classify_tta --split test --only 4:turns   # then the choice, once

``--rules occluded+kinect_v2,paper+kinect_v2`` takes the views by a depth camera (each shape at
a real piece's size, which the size prior then reads in metres) instead of the clean renders at
ModelNet's own sizes; each row also gives the top-1 of every class (``by_class``).

With ``--upright UPRIGHT.onnx`` (an upright classifier, ``itnet classify-train --upright``), each
view also has its up direction, the truth tilted ``--up-error`` degrees (2) in a seeded
direction, as a gravity sensor gives it, and two more modes: ``upright`` (that classifier on the
view levelled by its up, its K looks turned about +y, as the service classifies a request that
gives ``up``) and ``both`` (the K turned looks of the classifier for any orientation and the K
levelled looks of the upright one, all averaged).

``second`` is the service's default (``itnet/pose/recognition.py`` ``classify``, called as served):
one look, and only when its answer is under the card's threshold, K looks in all (the first
and K - 1 more, turned); ``second-upright`` the same with the up given (needs ``--upright``).
Their times are the whole call's (normalising and subsets too), with the mean looks a view got.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from itnet.metrics import paired_accuracy
from itnet.model.classify.configs import view_rule_names
from itnet.model.classify.data import class_names, load_splits, view_configs
from itnet.model.classify.size_prior import INCH_M, at_real_size, source_radii
from itnet.model.scanner import scan_of
from itnet.pose.recognition import classify, mean_log_probability, turned_looks
from itnet.pose.runtime import LoadedClassifier, load_any
from itnet.preprocess import estimate_normalization, shuffled_subset
from itnet.size_prior import with_size
from itnet.upright import sensed_ups

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=["val", "test"], default="val")
    parser.add_argument("--views", type=int, default=4, help="per shape, alternately occluded")
    parser.add_argument("--only", nargs="*", default=None, help="variants as K:mode")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared/data/modelnet10")
    parser.add_argument("--cache", type=Path, default=ROOT / "cache")
    parser.add_argument("--model", type=Path, default=ROOT / "itnet/models/classifier.onnx")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--upright", type=Path, default=None, help="an upright classifier")
    parser.add_argument("--up-error", type=float, default=2.0, help="degrees off the true up")
    parser.add_argument(
        "--rules",
        default="occluded,paper",
        help="view rules in turn, comma-separated: RULE, RULE+SENSOR (by that depth camera, "
        "each shape at a real piece's size), RULE+SENSOR+crop (cut out of a room), +clutter",
    )
    args = parser.parse_args()

    classifier = load_any(args.model, threads=2)
    if not isinstance(classifier, LoadedClassifier):
        raise SystemExit(f"{args.model} is not a classifier")
    classifier.warm_up()
    points = classifier.card.points
    classes = class_names(args.data)
    shapes = load_splits(args.data, classes, 0.1, 0, args.cache)[args.split]
    rng = np.random.default_rng(2024 if args.split == "test" else 7)
    try:
        configs = view_configs(view_rule_names(args.rules))
    except ValueError as err:
        parser.error(f"--rules: {err}")
    clouds, labels, metres, poses = [], [], [], []
    radii = source_radii(args.data, classes, args.split)  # ModelNet's units, read as inches
    for shape, label, radius in zip(shapes.shapes, shapes.labels, radii, strict=True):
        for v in range(args.views):
            config, size_m = configs[v % len(configs)], radius * INCH_M
            if config.sensor != "clean":  # by a camera: a real piece's size, in metres
                config, size_m = at_real_size(config, classes[label], rng)
            cloud, canonical_from_view = scan_of(shape, rng, config)
            poses.append(canonical_from_view)
            norm = estimate_normalization(cloud)
            clouds.append(norm.apply(cloud))
            labels.append(int(label))
            metres.append(norm.scale * size_m)
    prior = classifier.card.size_prior
    y = np.array(labels)
    given = sensed_ups(np.array(poses), args.up_error, np.random.default_rng(99))
    upright = None
    if args.upright is not None:
        upright = load_any(args.upright, threads=2)
        if not isinstance(upright, LoadedClassifier) or not upright.card.upright:
            raise SystemExit(f"{args.upright} is not an upright classifier")
        upright.warm_up()
    sizes = [len(c) for c in clouds]
    print(f"{len(clouds)} {args.split} views; points a view: median {int(np.median(sizes))}, "
          f"10th percentile {int(np.percentile(sizes, 10))}", flush=True)  # fmt: skip

    variants = [(1, "subsets"), (2, "subsets"), (4, "subsets"), (8, "subsets"),
                (2, "turns"), (4, "turns"), (8, "turns")]  # fmt: skip
    if args.only:
        variants = [(int(k), mode) for k, mode in (v.split(":") for v in args.only)]
    variants = [(1, "subsets")] + [v for v in variants if v != (1, "subsets")]  # the baseline first
    results: dict[str, dict] = {}
    first: np.ndarray | None = None  # one look's hits, the baseline of every paired gain
    first_sized: np.ndarray | None = None
    for k, mode in variants:
        hits, sized, ms = [], [], []
        looked = []  # second: the looks each view got
        for i, cloud in enumerate(clouds):
            rng = np.random.default_rng(i)
            if mode in ("second", "second-upright"):  # the service's own function, as served
                if mode == "second-upright" and upright is None:
                    raise SystemExit(f"{k}:{mode} needs --upright")
                classifier.upright = upright if mode == "second-upright" else None
                up = given[i] if mode == "second-upright" else None
                seen = classify(classifier, cloud, seed=i, up=up, second_looks=k)
                ms.append(seen.elapsed_ms)
                looked.append(seen.looks)
                hits.append(classes.index(seen.category) == y[i])
                if prior is not None:  # in metres, its unit said: the size counts
                    sized.append(classes.index(classify(
                        classifier, cloud * metres[i], seed=i, units="m", up=up, second_looks=k
                    ).category) == y[i])  # fmt: skip
                classifier.upright = None
                continue
            if mode in ("upright", "both"):
                if upright is None:
                    raise SystemExit(f"{k}:{mode} needs --upright")
                # drawn in the service's order (itnet/pose/recognition.py classify_together)
                x = turned_looks(cloud, k, points, rng) if mode == "both" else None
                stood = turned_looks(cloud, k, upright.card.points, rng, given[i])
                start = time.perf_counter()
                probs = upright.probabilities(stood)
                if x is not None:
                    probs = np.concatenate([classifier.probabilities(x), probs])
                ms.append((time.perf_counter() - start) * 1e3)
                score = mean_log_probability(probs)
                hits.append(int(score.argmax()) == y[i])
                if prior is not None:
                    sized.append(int(with_size(score, prior, metres[i]).argmax()) == y[i])
                continue
            if mode == "turns":
                x = turned_looks(cloud, k, points, rng)
            elif mode == "mirrored":  # the turned looks, every second one reflected in x
                x = turned_looks(cloud, k, points, rng)
                x[1::2, :, 0] *= -1
            else:
                x = np.stack([shuffled_subset(cloud, points, rng) for _ in range(k)])
                x = x.astype(np.float32)
            start = time.perf_counter()
            probs = classifier.probabilities(x)
            ms.append((time.perf_counter() - start) * 1e3)
            score = mean_log_probability(probs)
            hits.append(int(score.argmax()) == y[i])
            if prior is not None:  # the cloud's unit known: its size counts too
                sized.append(int(with_size(score, prior, metres[i]).argmax()) == y[i])
        hit = np.array(hits, float)
        first = hit if first is None else first
        alone = paired_accuracy(hit, first)
        row = {
            "top1": alone["accuracy"],
            "mean_class": round(100 * float(np.mean([hit[y == c].mean() for c in np.unique(y)])), 1),
            "gain": alone["gain"],
            "gain_stderr": alone["gain_stderr"],
            "median_ms": round(float(np.median(ms)), 2),
            "p90_ms": round(float(np.percentile(ms, 90)), 2),
        }  # fmt: skip
        if looked:
            row |= {"mean_ms": round(float(np.mean(ms)), 2),
                    "mean_looks": round(float(np.mean(looked)), 3),
                    "second_opinion_share": round(float(np.mean(np.array(looked) > 1)), 4)}  # fmt: skip
        row["by_class"] = {
            classes[c]: round(100 * float(hit[y == c].mean()), 1) for c in np.unique(y)
        }
        if sized:
            hit_sized = np.array(sized, float)
            first_sized = hit_sized if first_sized is None else first_sized
            both = paired_accuracy(hit_sized, first_sized)
            row |= {"top1_with_size": both["accuracy"], "gain_with_size": both["gain"],
                    "gain_with_size_stderr": both["gain_stderr"],
                    "by_class_with_size": {classes[c]: round(100 * float(hit_sized[y == c].mean()), 1)
                                           for c in np.unique(y)}}  # fmt: skip
        results[f"{k}:{mode}"] = row
        print(f"K={k} {mode:8s} {row}", flush=True)
    if args.out is not None:
        meta = {"split": args.split, "views": len(clouds), "rules": args.rules,
                "model": str(args.model),
                "upright": None if upright is None else str(args.upright),
                "up_error_deg": args.up_error}  # fmt: skip
        args.out.write_text(json.dumps({**meta, "results": results}, indent=1))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
