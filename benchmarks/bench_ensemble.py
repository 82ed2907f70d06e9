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
from pathlib import Path

from itnet.model.served_accuracy import known_ups, machine, measure, misses
from itnet.request_fields import parse_pair

__all__ = ["known_ups", "measure", "misses"]


SWITCH = {"default": None, "on": True, "off": False}  # the engine's default, always, never


def add_switch(parser: argparse.ArgumentParser, name: str, help: str) -> None:
    """An engine option the benchmark can leave to the engine (default), force on, or off."""
    parser.add_argument(name, choices=list(SWITCH), default="default", help=help)


def _pair(parser: argparse.ArgumentParser, text: str | None, option: str) -> tuple[int, int] | None:
    """'A,B' -> (A, B), two positive integers (None: not given); else the parser's error."""
    if text is None:
        return None
    try:
        return parse_pair(text)
    except ValueError:
        parser.error(f"{option} takes two positive integers")


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
    add_switch(
        parser,
        "--strip",
        "take away the floor and walls a cut-out kept: the engine's default (where up is given), "
        "always, never",
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
    parser.add_argument(
        "--coarse",
        default=None,
        metavar="ITERATIONS,POINTS",
        help="coarse first steps: the first ITERATIONS steps see at most POINTS of each run's "
        "points (default: the plan's)",
    )
    parser.add_argument(
        "--full",
        action="store_true",
        help="every run on all its points every step: no coarse steps and no halving, whatever "
        "the card's plan says (what --coarse and --halving are measured against)",
    )
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    parser.add_argument("--out", type=Path, default=Path("runs/ensemble_benchmark.json"))
    args = parser.parse_args()
    views = args.views or (4 if args.split == "val" else 5)
    mirror, centre = SWITCH[args.mirror], SWITCH[args.centre]
    baseline = json.loads(args.baseline.read_text()) if args.baseline else None
    halving, coarse = (_pair(parser, args.halving, "--halving AT,KEEP"),
                       _pair(parser, args.coarse, "--coarse ITERATIONS,POINTS"))  # fmt: skip
    results = {
        "machine": machine(),
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
        "coarse": args.coarse,
        "full": args.full,
        "strip": args.strip,
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
                coarse,
                args.full,
                SWITCH[args.strip],
            )
            for s in args.scanners
        },
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
