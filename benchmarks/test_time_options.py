"""What test-time options buy a trained pose model, on the validation views of its category.

Same weights, different ways of running them, 10 iterations each (the batch goes through the
onnxruntime graph, so use a float32 model: an int8 graph quantises a batch with one scale):

* a single run on 256 / 512 / 1,024 points of the cloud (the runtime uses the card's count);
* K fused runs (``itnet.fusion``, as the ensemble mode fuses them) on K random subsets, from K
  random starting rotations on one subset, and from K starts on K subsets;
* a single run, then refined by the object's mirror symmetry (``itnet.mirror``: every
  ModelNet10 class but the desk is left-right symmetric about its canonical x = 0 plane).

    python -m benchmarks.test_time_options --model itnet/models/chair-fp32.onnx --scanner surface
    python -m benchmarks.test_time_options --model runs/x.onnx --only "single run, 256"  # as served

Prints accuracy at (10°, 0.1 r) with its standard error, the rotation (< 10°) and centre
(< 0.1 r) accuracies, the median rotation error, and where the misses are: the share of scans
wrong in rotation only, in the centre only, or both; for the mirror refinement, its paired
gain and its median time per cloud. Validation views by default (the shapes held out of
training, seeded as ``itnet train`` seeds them): a choice made here can then be measured once on
the test split (``--split test``).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.fusion import fuse_poses
from itnet.geometry import random_rotation
from itnet.metrics import paired_accuracy
from itnet.mirror import mirror_finished
from itnet.model.categories import category
from itnet.model.category_set import test_scans, validation_scans
from itnet.model.evaluate import report
from itnet.model.scanner import VIEW_RULES, scan_config
from itnet.pose.runtime import LoadedModel, load_model
from itnet.preprocess import estimate_normalization, pose_from_normalized, resample

ITERATIONS = 10
MIRRORED = " + mirror"


def run_batch(model: LoadedModel, inputs: NDArray, starts: NDArray, chunk: int = 64) -> NDArray:
    """inputs (S, K, N, 3) normalised, starts (S, K, 3, 3) -> normalised poses (S, K, 4, 4)."""
    s, k = inputs.shape[:2]
    x = inputs.reshape(s * k, *inputs.shape[2:]).astype(np.float32)
    pose = np.tile(np.eye(4, dtype=np.float32), (s * k, 1, 1))
    pose[:, :3, :3] = starts.reshape(s * k, 3, 3)
    for b in range(0, s * k, chunk):
        for _ in range(ITERATIONS):
            pose[b : b + chunk], _ = model.step(x[b : b + chunk], pose[b : b + chunk])
    return pose.reshape(s, k, 4, 4)


def options(clouds: list[NDArray], rng: np.random.Generator) -> dict[str, tuple]:
    """Name -> (inputs (S, K, N, 3), starts (S, K, 3, 3)) for every option measured; a name
    ending in ``MIRRORED`` is also ``mirror_refined``."""
    s = len(clouds)

    def subsets(points: int, k: int) -> NDArray:
        return np.stack([[resample(c, points, rng) for _ in range(k)] for c in clouds])

    def identity(k: int) -> NDArray:
        return np.tile(np.eye(3), (s, k, 1, 1))

    out = {f"single run, {n} points": (subsets(n, 1), identity(1)) for n in (256, 512, 1024)}
    out[f"single run, 256 points{MIRRORED}"] = out["single run, 256 points"]
    for k in (4, 8):
        turns = random_rotation(rng, s * k).reshape(s, k, 3, 3)
        turns[:, 0] = np.eye(3)  # the first run starts where a single run does
        out[f"K={k}: subsets"] = (subsets(256, k), identity(k))
        out[f"K={k}: starts"] = (np.repeat(subsets(256, 1), k, axis=1), turns)
        out[f"K={k}: starts and subsets"] = (subsets(256, k), turns)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, default=Path("itnet/models/chair-fp32.onnx"))
    parser.add_argument("--scanner", default="occluded", choices=sorted(VIEW_RULES))
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    parser.add_argument(
        "--only", default="", help="Measure only the options whose name contains this text."
    )
    parser.add_argument(
        "--mirror-planes",
        default=None,
        help="planes of the mirror option, e.g. x or x,z (default: the model card's, else x)",
    )
    parser.add_argument("--plot", type=Path, default=None, help="write the rotation error CDFs")
    parser.add_argument(
        "--mirror-whole",
        action="store_true",
        help="refine by the mirror on the whole cloud, not on the run's subset (the engine's)",
    )
    parser.add_argument(
        "--split",
        choices=["val", "test"],
        default="val",
        help="test: the test views, once a choice was made on validation",
    )
    args = parser.parse_args()

    model = load_model(args.model, warm_up=False)
    symmetry = model.card.symmetry
    cat = category(model.card.category, symmetry)
    config = scan_config(VIEW_RULES[args.scanner])
    if args.split == "test":  # once, after the choice: itnet eval's and bench_ensemble's views
        scans, _ = test_scans(args.data, cat, 5, 2024, config, args.cache)
    else:
        scans = validation_scans(args.data, cat, scan=config, cache=args.cache)
    norms = [estimate_normalization(c) for c in scans.clouds]
    clouds = [n.apply(c) for n, c in zip(norms, scans.clouds)]
    print(f"{model.card.category} ({args.model.name}), {args.scanner} {args.split} views: "
          f"{len(clouds)} scans, median {int(np.median([len(c) for c in clouds]))} points")  # fmt: skip
    right: dict[str, NDArray] = {}  # option -> right or wrong per scan
    rotation_errors: dict[str, NDArray] = {}  # option -> final rotation error per scan
    planes = (args.mirror_planes or ",".join(model.card.mirror_planes) or "x").split(",")
    for name, (inputs, starts) in options(clouds, np.random.default_rng(0)).items():
        if args.only not in name:
            continue
        poses = run_batch(model, inputs, starts)
        fused = np.stack([fuse_poses(p, symmetry) for p in poses])
        if name.endswith(MIRRORED):
            seconds = []
            # on the run's own subset, as the engine does (``--mirror-whole``: the whole cloud)
            mirror_on = clouds if args.mirror_whole else list(inputs[:, 0].astype(np.float64))
            for i, (cloud, pose) in enumerate(zip(mirror_on, fused)):
                start = time.perf_counter()
                fused[i] = mirror_finished(cloud, pose, planes)
                seconds.append(time.perf_counter() - start)
            print(f"  mirror refinement ({','.join(planes)}): median "
                  f"{1e3 * np.median(seconds):.1f} ms a cloud")  # fmt: skip
        final = np.stack([pose_from_normalized(f, n) for f, n in zip(fused, norms)])
        rep, rot, trans = report(final[:, None], scans, symmetry)
        acc = rep.accuracy[-1]
        turned, shifted = rot[:, -1] >= 10, trans[:, -1] >= 0.1
        right[name] = ~(turned | shifted)
        rotation_errors[
            f"{name}{' (' + ','.join(planes) + ')' if name.endswith(MIRRORED) else ''}"
        ] = rot[:, -1]
        unrefined = right.get(name.removesuffix(MIRRORED)) if name.endswith(MIRRORED) else None
        if unrefined is not None:  # the same subsets, refined or not: a paired gain
            gain = paired_accuracy(right[name], unrefined)
            print(f"  the mirror's paired gain: {gain['gain']:+.1f} ± {gain['gain_stderr']:.1f}")
        print(
            f"{name:37s} {100 * acc:5.1f} ± {100 * math.sqrt(acc * (1 - acc) / rep.scans):.1f} %"
            f"   rotation < 10°: {100 * rep.rotation_accuracy[-1]:5.1f} %"
            f"   centre < 0.1 r: {100 * rep.translation_accuracy[-1]:5.1f} %"
            f"   median rotation error {rep.median_rotation_deg[-1]:.1f}°"
            f"   missed in rotation only / centre only / both: "
            f"{100 * np.mean(turned & ~shifted):.1f} / {100 * np.mean(shifted & ~turned):.1f}"
            f" / {100 * np.mean(turned & shifted):.1f} %",
            flush=True,
        )

    if args.plot is not None:
        from itnet.model.plots import plot_rotation_cdfs

        title = (f"{model.card.category} ({args.model.name}), {args.scanner} {args.split} views, "
                 f"{len(clouds)} scans, 10 iterations")  # fmt: skip
        print(f"wrote {plot_rotation_cdfs(rotation_errors, args.plot, title)}")


if __name__ == "__main__":
    main()
