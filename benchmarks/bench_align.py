"""Benchmark: itnet-align against the composed poses and registration baselines, on pairs of
partial scans from three pair generators.

    .venv/bin/python -m benchmarks.bench_align --pairs 100                      # validation
    .venv/bin/python -m benchmarks.bench_align --pairs 100 --split test --out docs  # measured once
    .venv/bin/python -m benchmarks.bench_align --model table --generators camera
    .venv/bin/python -m benchmarks.bench_align --pairs 100 --up 2 --only "itnet-align --up"
    .venv/bin/python -m benchmarks.bench_align --pairs 100 --sensor kinect_v2 --generators any_view paper

Pairs (``benchmarks.align_pairs``): two partial scans of the same held-out object (the model's
category from ModelNet10: the validation shapes its training left out, or the test split), from
each generator of ``--generators``: ``any_view`` (two viewpoints from any direction),
``camera`` (a Kinect v2 above the floor, real sizes, each scan from its own distance) and
``overlap`` (a RealSense D435, the second view turned 15-180 degrees about up: overlap from
nearly all to almost none) and ``paper`` (two viewpoints from any direction by the IT-Net
paper's rule, no noise); ``--sensor CAMERA`` puts every generator's scans through that
camera's model instead, the object at its real size. Seeded, so every method sees the same pairs. Metric (SPEC.md):
rotation error and the distance between where the estimate and the truth put A's centroid,
over the object radius, the least over the category's symmetric equivalents; success at
(10 deg, 0.1). "composed poses" is inv(T_canonical_from_b) · T_canonical_from_a of the two
served poses alone, the prior itnet-align must never be worse than (paired, per generator);
"composed served poses" composes the poses ``itnet pose --budget-ms 1000 --no-schedule`` serves
(the card's fused runs, every step).
``--up ERROR_DEG`` adds the itnet-align variants given each scan's up direction, tilted by that
error as a gravity sensor's would be; a model whose card requires up runs only those
(``itnet-align --sweep 0 --up``: without the turns about up tried from the composed pose). Writes
align_benchmark.{md,png,json} to ``--out`` (runs/align by default; the README's is ``--out docs``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from benchmarks import baselines
from benchmarks.align_pairs import GENERATORS, Pair, make_pairs, split_shapes
from benchmarks.report import write_report
from itnet.alignment.estimators import in_process_estimator
from itnet.alignment.pipeline import POSE_SHARE, align_clouds
from itnet.alignment.request import DEFAULT_BUDGET_MS, AlignRequest
from itnet.metrics import is_correct
from itnet.model.sensor import SENSORS
from itnet.pose.catalog import Catalog
from itnet.pose.runtime import LoadedModel
from itnet.upright import tilted

ROOT = Path(__file__).resolve().parents[1]
SERVED_BUDGET_MS = 1000.0  # each cloud's, for "composed served poses": every step of every run


@dataclass
class Outcome:
    """Per-pair errors and times of one method (pairs it ran on, in order)."""

    rotation_deg: list[float] = field(default_factory=list)
    translation: list[float] = field(default_factory=list)
    ms: list[float] = field(default_factory=list)
    info: list[dict] = field(default_factory=list)
    generator: list[str] = field(default_factory=list)

    def success(self) -> NDArray[np.bool_]:
        return is_correct(np.array(self.rotation_deg), np.array(self.translation))


def resampled(pairs: list[Pair], count: int, seed: int) -> None:
    """Each scan resampled to ``count`` points: a seeded subset, or every point and repeats of
    some jittered by 0.005 radii."""
    rng = np.random.default_rng(seed)

    def one(points: NDArray) -> NDArray:
        if len(points) >= count:
            return points[rng.choice(len(points), count, replace=False)]
        extra = points[rng.choice(len(points), count - len(points))]
        return np.concatenate([points, extra + rng.normal(scale=0.005, size=extra.shape)])

    for pair in pairs:
        pair.a, pair.b = one(pair.a), one(pair.b)


def given_ups(pairs: list[Pair], error_deg: float, seed: int) -> None:
    """Each pair's ups as a gravity sensor would give them: tilted by ``error_deg``."""
    rng = np.random.default_rng(seed)
    for pair in pairs:
        pair.ups = tuple(tilted(np.stack(pair.ups), error_deg, rng))  # type: ignore[assignment]


def itnet_methods(
    model_name: str, model_dir: Path | None, budget_ms: float, with_up: bool = False
) -> tuple[dict[str, Callable], LoadedModel]:
    """itnet-align variants (the CLI's options in the name), each returning (T_b_from_a, info);
    ``with_up``: also each with ``--up`` (it then takes the pair's ups; only those where the
    model requires up). "composed poses" is the two served poses composed, nothing else;
    "composed poses + ICP" that pose refined, no rival ever judged."""
    catalog = Catalog.load(model_dir)
    model = catalog.model(model_name)
    variants = {
        "composed poses": AlignRequest(budget_ms=budget_ms, rivals=False, refine=False),
        "composed poses + ICP": AlignRequest(budget_ms=budget_ms, rivals=False, refine=True),
        # each cloud's pose as ``itnet pose --budget-ms 1000`` serves it: the card's runs
        "composed served poses": AlignRequest(
            budget_ms=SERVED_BUDGET_MS / POSE_SHARE,
            starts=model.card.recommended_ensemble,
            rivals=False,
            refine=False,
        ),
        "itnet-align": AlignRequest(budget_ms=budget_ms, refine=True),
        # with the ups: no turns about up tried from the composed pose
        "itnet-align --sweep 0": AlignRequest(budget_ms=budget_ms, refine=True, sweep=0),
    }

    def method(request: AlignRequest, up: bool) -> Callable:
        estimate = in_process_estimator(catalog, request.pose_request(model_name))
        options = request.options(model.card, bool(request.refine))

        def align(a: NDArray, b: NDArray, ups: tuple | None = None) -> tuple[NDArray, dict]:
            result = align_clouds(a, b, estimate, options, *(ups if up else (None, None)))
            chosen = result.hypotheses[result.chosen].source
            info = {"probability": result.probability, "hypothesis": chosen,
                    "iterations": result.iterations, "considered": result.considered,
                    **{f"{k}_ms": v for k, v in result.timings_ms.items()}}  # fmt: skip
            return result.T_b_from_a, info

        align.uses_up = up  # type: ignore[attr-defined]
        return align

    out = {}
    for name, request in variants.items():
        if not model.card.requires_up and request.sweep:  # without ups, --sweep 0 is itnet-align
            out[name] = method(request, False)
        if with_up or model.card.requires_up:
            out[f"{name} --up"] = method(request, True)
    return out, model


def run_methods(methods: dict[str, Callable], pairs: list[Pair], seconds: float) -> dict:
    """Every method on every pair, interleaved pair by pair (so a change in the machine's load
    hits all methods alike), after one warm-up call each; a method stops once it has spent
    ``seconds``. Returns {name: Outcome}."""
    for method in methods.values():
        method(pairs[0].a, pairs[0].b, **_ups(method, pairs[0]))
    outcomes = {name: Outcome() for name in methods}
    for pair in pairs:
        for name, method in methods.items():
            out = outcomes[name]
            if sum(out.ms) / 1e3 > seconds:
                continue
            start = time.perf_counter()
            reply = method(pair.a, pair.b, **_ups(method, pair))
            out.ms.append((time.perf_counter() - start) * 1e3)
            estimate, info = reply if isinstance(reply, tuple) else (reply, {})
            rot, trans = pair.errors(estimate)
            out.rotation_deg.append(rot)
            out.translation.append(trans)
            out.info.append(info)
            out.generator.append(pair.generator)
    return outcomes


def _ups(method: Callable, pair: Pair) -> dict:
    """The pair's ups for a method that takes them (itnet-align --up), else nothing."""
    return {"ups": pair.ups} if getattr(method, "uses_up", False) else {}


def _without_notes(argv: list[str]) -> list[str]:
    """The command line without ``--note TEXT`` pairs (the notes are printed apart)."""
    out, skip = [], False
    for arg in argv:
        if skip or arg == "--note":
            skip = arg == "--note"
            continue
        out.append(arg)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared/data/modelnet10",
                        help="ModelNet10's folder (CATEGORY/train, CATEGORY/test)")  # fmt: skip
    parser.add_argument("--split", choices=("validation", "test"), default="validation",
                        help="validation: choose on it; test: measure once")  # fmt: skip
    parser.add_argument("--pairs", type=int, default=100)
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--model", default="chair")
    parser.add_argument("--model-dir", type=Path, default=None)
    parser.add_argument("--generators", nargs="+", default=list(GENERATORS))
    parser.add_argument("--points", type=int, default=None,
                        help="resample every scan to this many points (a timing at a size the "
                        "scans do not reach: repeated points jittered by 0.005 radii)")  # fmt: skip
    parser.add_argument("--budget-ms", type=float, default=DEFAULT_BUDGET_MS,
                        help="the whole alignment's")  # fmt: skip
    parser.add_argument("--seconds-per-method", type=float, default=120.0)
    parser.add_argument("--only", nargs="*", default=None, help="method names to run")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "align",
                        help="where the report goes; docs for the README's")  # fmt: skip
    parser.add_argument("--note", action="append", default=[], help="a line for the report")
    parser.add_argument("--sensor", default=None, choices=sorted(SENSORS),
                        help="every generator's scans by this camera's model, at real size "
                        "(default: each generator's own)")  # fmt: skip
    parser.add_argument("--up", type=float, default=None, metavar="ERROR_DEG",
                        help="add itnet-align given each scan's up, tilted by ERROR_DEG")  # fmt: skip
    parser.add_argument(
        "--from-json",
        type=Path,
        default=None,
        help="only re-render the .md and .png from a saved align_benchmark.json",
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.from_json is not None:
        saved = json.loads(args.from_json.read_text())
        results = {name: Outcome(**r) for name, r in saved["results"].items()}
        write_report(results, saved["meta"], args.out / "align_benchmark")
        return

    methods, model = itnet_methods(args.model, args.model_dir, args.budget_ms, args.up is not None)
    category = model.card.category or "chair"
    shapes = split_shapes(args.data, category, args.split)
    pairs = [pair for k, generator in enumerate(args.generators)
             for pair in make_pairs(generator, shapes, args.pairs, args.seed + k, category,
                                    args.sensor)]  # fmt: skip
    if args.points is not None:
        resampled(pairs, args.points, args.seed + 2)
    given_ups(pairs, 2.0 if args.up is None else args.up, args.seed + 1)
    methods.update(baselines.available())
    if args.only:
        methods = {name: m for name, m in methods.items() if name in args.only}
    results = run_methods(methods, pairs, args.seconds_per_method)
    for name, outcome in results.items():
        ok = outcome.success()
        print(f"{name:40s} {ok.mean():6.1%} of {len(ok)}  median "
              f"{np.median(outcome.ms):7.1f} ms", flush=True)  # fmt: skip
    model_stat = model.path.stat()
    shipped = model.path.parent.name == "models" and model.path.parent.parent.name == "itnet"
    digest = hashlib.sha256(model.path.read_bytes()).hexdigest()[:12]
    meta = {
        "pairs": len(pairs),
        "generators": args.generators,
        "sensor": args.sensor,
        "category": category,
        "seed": args.seed,
        "split": args.split,
        "data": str(args.data),
        "model": f"`{model.card.name}` ({'itnet/models/' + model.path.name if shipped else model.path}, "
        f"{model_stat.st_size // 1024} KB, sha256 {digest}…)",
        "budget_ms": args.budget_ms,
        "up_error_deg": args.up,
        "command": " ".join(["python -m benchmarks.bench_align", *_without_notes(sys.argv[1:])]),
        "notes": args.note + ([f"Every scan resampled to {args.points} points (repeats "
                               "jittered by 0.005 radii)."] if args.points else []),
        "points": [int(np.median([len(p.a) for p in pairs])),
                   int(np.median([len(p.b) for p in pairs]))],
    }  # fmt: skip
    write_report(results, meta, args.out / "align_benchmark")
    dump = {name: {"rotation_deg": o.rotation_deg, "translation": o.translation, "ms": o.ms,
                   "info": o.info, "generator": o.generator}
            for name, o in results.items()}  # fmt: skip
    (args.out / "align_benchmark.json").write_text(json.dumps({"meta": meta, "results": dump}))


if __name__ == "__main__":
    main()
