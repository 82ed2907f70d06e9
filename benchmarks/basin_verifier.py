"""The ensemble's runs anchored by the one that sits most firmly in its basin, on *validation* views.

K runs per scan as the engine runs an ensemble (turned starts, own subsets, 10 iterations, no
time limit; ``itnet.model.evaluate.run_poses``), then three answers on the same runs:

* ``fused``: the fusion as served (``itnet.fusion``: the medoid's inliers);
* ``anchored``: the fusion anchored by the run with the least drift (``itnet.basin``: each pose
  knocked off by four ``--probe-deg`` turns, ``--probe-steps`` steps back);
* ``unless the medoid holds``: the same, only where the medoid drifts more than
  ``itnet.basin.UNSURE_DEG`` (``firm_anchor``: what ``verify`` serves);
* ``any run right``: the oracle, what a perfect choice among the runs would score.

    python -m benchmarks.basin_verifier --model itnet/models/chair-fp32.onnx --ensemble 8

Prints, per kind of view, each answer's accuracy at (10°, 0.1 r) with its paired gain over
``fused``, and the probes' cost in network steps. The test split is not touched.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from itnet.basin import PROBE_DEG, PROBE_STEPS, basin_drift, firm_anchor, probe_turns
from itnet.fusion import fuse_poses, medoid_index
from itnet.geometry import viewing_axis_turns
from itnet.metrics import is_correct, paired_accuracy
from itnet.model.categories import category
from itnet.model.category_set import validation_scans
from itnet.model.data import ScanSet
from itnet.model.evaluate import report, run_poses
from itnet.model.scanner import VIEW_RULES, scan_config
from itnet.pose.runtime import load_model
from itnet.preprocess import pose_from_normalized


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, default=Path("itnet/models/chair-fp32.onnx"))
    parser.add_argument("--ensemble", type=int, default=8)
    parser.add_argument("--probe-deg", type=float, default=PROBE_DEG)
    parser.add_argument("--probe-steps", type=int, default=PROBE_STEPS)
    parser.add_argument("--views", type=int, default=12)
    parser.add_argument("--scanners", nargs="+", default=["paper", "occluded"])
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = parser.parse_args()

    model = load_model(args.model, warm_up=False)
    cat = category(model.card.category, model.card.symmetry)
    turns, starts = probe_turns(args.probe_deg), viewing_axis_turns(args.ensemble)

    def step(x: np.ndarray, pose: np.ndarray) -> np.ndarray:
        return model.step(x, pose)[0]

    results: dict[str, dict] = {}
    for scanner in args.scanners:
        config = scan_config(VIEW_RULES[scanner])
        scans = validation_scans(args.data, cat, views=args.views, scan=config, cache=args.cache)
        answers: dict[str, list[bool]] = {
            "fused": [],
            "anchored": [],
            "unless the medoid holds": [],
            "any run right": [],
        }
        for i, cloud in enumerate(scans.clouds):
            poses, x, norm = run_poses(model, cloud, starts, i)
            drift = basin_drift(step, x, poses, turns, args.probe_steps)
            medoid = medoid_index(poses, cat.symmetry)
            candidates = [
                fuse_poses(poses, cat.symmetry),
                fuse_poses(poses, cat.symmetry, anchor=int(np.argmin(drift))),
                fuse_poses(poses, cat.symmetry, anchor=firm_anchor(drift, medoid)),
                *poses,
            ]
            moved = np.stack([pose_from_normalized(p, norm) for p in candidates])
            n = len(moved)
            one = ScanSet(
                [cloud] * n,
                np.repeat(scans.poses[i : i + 1], n, 0),
                np.repeat(scans.radii[i : i + 1], n),
                [scans.names[i]] * n,
            )
            _, rot, trans = report(moved[:, None], one, cat.symmetry)
            ok = is_correct(rot[:, -1], trans[:, -1])
            answers["fused"].append(bool(ok[0]))
            answers["anchored"].append(bool(ok[1]))
            answers["unless the medoid holds"].append(bool(ok[2]))
            answers["any run right"].append(bool(ok[3:].any()))
        fused = np.array(answers["fused"], float)
        results[scanner] = {
            k: paired_accuracy(np.array(v, float), fused) for k, v in answers.items()
        }
        cells = [
            f"{k} {r['accuracy']:.1f}% ({r['gain']:+.1f} ± {r['gain_stderr']:.1f})"
            for k, r in results[scanner].items()
        ]
        print(f"{model.card.name} {scanner}, {len(fused)} scans, K={args.ensemble}: "
              + "   ".join(cells), flush=True)  # fmt: skip
    probes = len(turns) * args.probe_steps
    print(f"cost: the runs' 10 steps, then {args.probe_steps} steps of {len(turns)} probes a run "
          f"({probes / 10:.1f}x the runs' steps)")  # fmt: skip
    if args.json:
        meta = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
        args.json.write_text(json.dumps({"args": meta, "results": results}, indent=1))


if __name__ == "__main__":
    main()
