"""The ensemble accuracy mode against a single run, within one time budget, as the service runs it.

For every held-out test scan of a category (the same seeded views as ``itnet eval``), one
``AnytimeRun`` per setting (K = 1, 4, 8 fused runs) under the same ``budget_ms``; prints and
writes accuracy at (10°, 0.1 r) with its standard error, the gain over the first setting on the
same scans (paired, with its standard error), the median iterations and elapsed time::

    python -m benchmarks.bench_ensemble --model itnet/models/chair.onnx --budget-ms 20
"""

from __future__ import annotations

import argparse
import json
import platform
from dataclasses import replace
from pathlib import Path

import numpy as np


def known_ups(poses: np.ndarray, error_deg: float, seed: int = 0) -> np.ndarray:
    """Each scan's up direction in its own frame, as a caller would give it: the truth (the
    canonical +y taken back by T_canonical_from_input (S, 4, 4)) tilted by ``error_deg`` about a
    random horizontal axis (a gravity sensor's error) -> (S, 3) unit vectors."""
    from itnet.upright import sensed_ups

    return sensed_ups(poses, error_deg, np.random.default_rng(seed))


def misses(rot_deg: np.ndarray, trans: np.ndarray) -> dict[str, float]:
    """Where the misses are, % of all scans: near misses in rotation (10–20°), wrong basins
    (over 20°; of them, turned by more than 135°: a front-back swap where up is given), and the
    centre over 0.1 r with the rotation right. (S,), (S,) -> shares."""
    share = lambda mask: round(100.0 * float(np.mean(mask)), 1)  # noqa: E731
    return {
        "rot_10_20": share((rot_deg >= 10) & (rot_deg < 20)),
        "rot_over_20": share(rot_deg >= 20),
        "rot_over_135": share(rot_deg > 135),
        "centre_only": share((rot_deg < 10) & (trans >= 0.1)),
    }


def measure(model_path: Path, scanner: str, ensembles: list[int], budget_ms: float,
            views: int, cache: Path, data: Path, split: str = "test",
            mirror: bool | None = None, centre: bool | None = None,
            baseline: dict | None = None, viewpoint: bool = False,
            up_error_deg: float | None = None, verify: bool | None = None,
            verifier: str = "beside", recheck: bool | None = None,
            halving: tuple[int, int] | None = None,
            points: int | None = None) -> dict:  # fmt: skip
    from itnet.metrics import is_correct, paired_accuracy
    from itnet.model.categories import category
    from itnet.model.category_set import test_scans, validation_scans
    from itnet.model.evaluate import report
    from itnet.model.scanner import named_views
    from itnet.pose.loop import AnytimeRun
    from itnet.pose.plan import plan
    from itnet.pose.request import PoseRequest
    from itnet.pose.runtime import (
        LoadedVerifier,
        attach_verifiers,
        load_any,
        load_beside,
        load_model,
    )

    model = load_model(model_path)
    if points is not None:  # each run's points, as a card that says so would have them
        model.card = model.card.model_copy(update={"points": points})
    if verifier == "beside":  # as the service loads the model's folder
        found = load_beside(model_path.parent, skip=frozenset({model_path.resolve()}))[1]
        attach_verifiers({model.card.name: model}, found, model_path.parent)
    elif verifier != "none":  # verify then anchors on the run it finds likeliest
        model.verifier = load_any(Path(verifier))
        assert isinstance(model.verifier, LoadedVerifier), f"{verifier}: not a verifier"
    cat = category(model.card.category, model.card.symmetry)
    config = named_views(scanner, cat.name)
    if split == "val":  # where a choice is made; the test split measures it once
        scans = validation_scans(data, cat, views, scan=config, cache=cache)
    else:
        scans, _ = test_scans(data, cat, views, 2024, config, cache)
    ups = None if up_error_deg is None else known_ups(scans.poses, up_error_deg)
    out, first = {}, None
    for k in ensembles:
        poses, iterations, elapsed, mirrored, runs, verified = [], [], [], [], [], []
        rechecked = []
        for i, cloud in enumerate(scans.clouds):
            request = PoseRequest(
                budget_ms=budget_ms,
                ensemble=k or None,  # 0: the plan's default (the card's, as the budget holds)
                mirror=mirror,
                centre=centre,
                viewpoint=[0.0, 0.0, 0.0] if viewpoint else None,  # the scanner's camera
                up=None if ups is None else [float(v) for v in ups[i]],
                verify=verify if k != 1 else None,
                recheck=recheck if k == 1 else None,
            )
            planned = plan(model, request)
            if halving is not None:  # the runs the verifier likes best go on after halving[0]
                planned = replace(planned, halving=halving)
            run = AnytimeRun(planned, cloud)
            last = run.run_to_end()
            result = run.result()
            verified.append(result.get("verified"))
            rechecked.append(result.get("rechecked"))
            poses.append(last.pose)
            iterations.append(run.iteration)
            elapsed.append(run.elapsed_ms())
            mirrored.append(result.get("mirror"))
            runs.append(result["ensemble"])
        _, rot, trans = report(np.stack(poses)[:, None], scans, cat.symmetry)  # symmetry-aware
        correct = is_correct(rot[:, -1], trans[:, -1]).astype(float)
        first = correct if first is None else first
        # against another run of this benchmark on the same scans (--baseline): paired
        before = (baseline or {}).get(scanner, {}).get(str(k), {}).get("correct")
        versus = (
            {"versus_baseline": paired_accuracy(correct, [c == "1" for c in before])}
            if before is not None and len(before) == len(correct)
            else {}
        )
        out[str(k)] = {
            # gain: against the first setting on the same scans (paired), with its s.e.
            **paired_accuracy(correct, first),
            "misses": misses(rot[:, -1], trans[:, -1]),
            **versus,
            "median_iterations": float(np.median(iterations)),
            **({"runs": {str(r): runs.count(r) for r in sorted(set(runs))}} if k == 0 else {}),
            "median_elapsed_ms": round(float(np.median(elapsed)), 2),
            "p99_elapsed_ms": round(float(np.percentile(elapsed, 99)), 2),
            # where the model's mirror planes were on: the share of runs they finished in time
            **(
                {"mirror_finished": round(float(np.mean([m is True for m in mirrored])), 3)}
                if any(m is not None for m in mirrored)
                else {}
            ),
            # where recheck was on: the share of runs the verifier doubted, and rechecked in time
            **(
                {
                    "doubted": round(float(np.mean([r is not None for r in rechecked])), 3),
                    "rechecked": round(float(np.mean([r is True for r in rechecked])), 3),
                }
                if "recheck" in run.plan.stage_names
                else {}
            ),
            # where verify was on: the share of runs whose probes the budget held
            **(
                {"verified": round(float(np.mean([v is True for v in verified])), 3)}
                if any(v is not None for v in verified)
                else {}
            ),
        }
        print(scanner, f"K={k}", out[str(k)], flush=True)
        out[str(k)]["correct"] = "".join("1" if c else "0" for c in correct)  # per scan, in order
    return out


SWITCH = {"default": None, "on": True, "off": False}  # the engine's default, always, never


def add_switch(parser: argparse.ArgumentParser, name: str, help: str) -> None:
    """An engine option the benchmark can leave to the engine (default), force on, or off."""
    parser.add_argument(name, choices=list(SWITCH), default="default", help=help)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, default=Path("itnet/models/chair.onnx"))
    parser.add_argument("--budget-ms", type=float, default=20.0)
    parser.add_argument(
        "--ensembles", type=int, nargs="+", default=[1, 4, 8], help="0: the engine's default"
    )
    parser.add_argument(
        "--views", type=int, default=None, help="views per shape (default: 5 test, 4 val)"
    )
    parser.add_argument(
        "--split",
        choices=["test", "val"],
        default="test",
        help="val: itnet train's validation views (held-out training shapes)",
    )
    parser.add_argument(
        "--scanners",
        nargs="+",
        default=["occluded", "surface", "paper"],
        help="view rules, each RULE or RULE+SENSOR: seen by a depth camera (model.sensor.SENSORS: "
        "kinect_v1, kinect_v2, realsense_d435) at the category's real sizes",
    )
    add_switch(
        parser,
        "--mirror",
        "finish by the card's mirror planes: the engine's default (single runs), always, never",
    )
    add_switch(
        parser,
        "--centre",
        "finish the centre by the card's correction: the engine's default (where the card has "
        "one), always, never",
    )
    parser.add_argument(
        "--viewpoint",
        action="store_true",
        help="give the engine the sensor's position (the scans' origin, where the scanner's "
        "camera is): the card's viewpoint correction finishes the centre",
    )
    parser.add_argument(
        "--up",
        type=float,
        default=None,
        metavar="ERROR_DEG",
        help="give the engine each scan's up direction, tilted from the truth by ERROR_DEG "
        "(0: exact; 2: a phone-grade gravity sensor): the poses are held upright",
    )
    parser.add_argument(
        "--baseline",
        type=Path,
        default=None,
        help="a JSON of this benchmark on the same scans: adds each setting's paired gain over it",
    )
    add_switch(
        parser,
        "--verify",
        "anchor fused runs by the firmest one (itnet.basin): the card's default, always (K > 1), "
        "never",
    )
    add_switch(
        parser,
        "--recheck",
        "recheck a single run the verifier doubts: the card's default, always, never",
    )
    parser.add_argument(
        "--verifier",
        default="beside",
        help="the learned verifier beside the model: 'beside' (default: the one of its category "
        "in the model's folder, as the service loads it), 'none' (verify runs the probes; no "
        "recheck), or a path (.onnx of itnet verifier-export)",
    )
    parser.add_argument(
        "--halving",
        default=None,
        metavar="AT,KEEP",
        help="successive halving: after AT iterations only the KEEP runs the verifier finds "
        "likeliest go on (default: the plan's)",
    )
    parser.add_argument(
        "--points",
        type=int,
        default=None,
        help="the most points a run sees of a scan (default: the model card's)",
    )
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    parser.add_argument("--out", type=Path, default=Path("runs/ensemble_benchmark.json"))
    args = parser.parse_args()
    views = args.views or (4 if args.split == "val" else 5)
    mirror, centre = SWITCH[args.mirror], SWITCH[args.centre]
    baseline = json.loads(args.baseline.read_text()) if args.baseline else None
    halving = None if args.halving is None else tuple(int(v) for v in args.halving.split(","))
    if halving is not None and (len(halving) != 2 or min(halving) < 1):
        parser.error("--halving takes AT,KEEP: two positive integers")
    results = {
        "machine": f"{platform.processor() or platform.machine()}, {__import__('os').cpu_count()} cores",
        "model": str(args.model),
        "budget_ms": args.budget_ms,
        "split": args.split,
        "views": views,
        "mirror": args.mirror,
        "centre": args.centre,
        "viewpoint": args.viewpoint,
        "up_error_deg": args.up,
        "verify": args.verify,
        "recheck": args.recheck,
        "verifier": args.verifier,
        "halving": args.halving,
        "points": args.points,
        **({"baseline": str(args.baseline)} if args.baseline else {}),
        **{
            s: measure(
                args.model,
                s,
                args.ensembles,
                args.budget_ms,
                views,
                args.cache,
                args.data,
                args.split,
                mirror,
                centre,
                baseline,
                args.viewpoint,
                args.up,
                SWITCH[args.verify],
                args.verifier,
                SWITCH[args.recheck],
                halving,
                args.points,
            )
            for s in args.scanners
        },
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
