"""Fit the alignment's calibrated choice on validation pairs, and see what each setting does.

    .venv/bin/python -m benchmarks.align_calibrate --pairs 40 --generators any_view camera \
        overlap --write itnet/alignment/calibration.json --json docs/align_calibration.json

For every category of ``--categories`` and every pair generator (``benchmarks.align_pairs``),
validation pairs of held-out shapes are aligned with every rival judged (``sure`` above 1;
``--refine``: refined by ICP as ``itnet-align`` judges them, without it, or both), and
each judged candidate's evidence (``itnet.alignment.choice.FEATURES``) is kept with whether it is
right (10 degrees, 0.1 radii). A logistic model is fitted on all of them (``--write``: the
shipped calibration), then the choice is replayed on the same pairs for each threshold of
``--sure`` (the composed pose this likely right is answered without rivals): success per
generator, paired against the composed poses alone, and how often rivals were judged. The
reliability table says, of the answers given each probability, how many were right.
"""

from __future__ import annotations

import argparse
import json
import time
from itertools import product
from pathlib import Path

import numpy as np

from benchmarks.align_pairs import GENERATORS, make_pairs, split_shapes
from benchmarks.report import reliability
from itnet.alignment.choice import FEATURES, Calibration, fit_logistic, probability
from itnet.alignment.estimators import in_process_estimator
from itnet.alignment.hypotheses import rival_turns
from itnet.alignment.pipeline import AlignOptions, align_clouds
from itnet.metrics import paired_accuracy
from itnet.pose.catalog import Catalog
from itnet.pose.request import PoseRequest

ROOT = Path(__file__).resolve().parents[1]
SURE = (0.6, 0.7, 0.8, 0.9, 0.95, 1.01)


def collect(catalog: Catalog, category: str, generator: str, pairs: int, seed: int,
            data: Path, budget_ms: float, ensemble: int | None = None,
            candidates: int = 6, finalists: int = 3, refine: bool = True,
            schedule: bool | None = None) -> list[dict]:  # fmt: skip
    """Every pair's judged candidates: evidence, right or not, composed or rival (``refine``:
    each refined by ICP, as ``itnet-align`` judges them with open3d; else as without it;
    ``schedule``: the poses on the card's schedule, as the alignment's request asks)."""
    model = catalog.model(category)
    card = model.card
    estimate = in_process_estimator(
        catalog,
        PoseRequest(model=category, budget_ms=budget_ms, ensemble=ensemble, schedule=schedule),
    )
    options = AlignOptions(symmetry=rival_turns(card.category, card.symmetry),
                           refine=refine, sure=2.0, candidates=candidates,
                           finalists=finalists)  # fmt: skip
    out = []
    for pair in make_pairs(generator, split_shapes(data, category, "validation"), pairs, seed,
                           category):  # fmt: skip
        ups = pair.ups if card.requires_up else (None, None)
        result = align_clouds(pair.a, pair.b, estimate, options, *ups)
        rows, right = [], []
        for h in result.hypotheses:
            rows.append(h.evidence.tolist())
            right.append(pair.right(h.T_b_from_a))
        composed = sum(1 for h in result.hypotheses if h.served and not h.turned)
        out.append({"category": category, "generator": generator, "rows": rows, "right": right,
                    "composed": composed, "ms": result.timings_ms, "refine": refine})  # fmt: skip
    return out


def replay(records: list[dict], calibration: Calibration, sure: float) -> dict:
    """The choice at threshold ``sure`` on the collected pairs: chosen right or not, its
    probability, whether rivals were judged, and the composed pose's own result."""
    chosen, probs, rivals, composed = [], [], [], []
    for r in records:
        p = probability(np.array(r["rows"]), calibration)
        k = r["composed"]
        looked = p[:k].max() < sure
        pick = int(np.argmax(p if looked else p[:k]))
        move = np.array(r["rows"])[:, FEATURES.index("move")]
        if pick == 0 and k > 1 and move[1] < 1.0:  # about within 10 degrees and 0.1 radii
            pick = 1  # the composed pose sharpened by ICP (itnet.alignment.pipeline)
        chosen.append(r["right"][pick])
        probs.append(float(p[pick]))
        rivals.append(looked)
        composed.append(r["right"][0])
    return {"right": np.array(chosen), "probability": np.array(probs),
            "rivals": np.array(rivals), "composed": np.array(composed)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared/data/modelnet10")
    parser.add_argument("--categories", nargs="+",
                        default=["chair", "table", "sofa", "bed", "monitor", "toilet"])  # fmt: skip
    parser.add_argument("--generators", nargs="+", default=list(GENERATORS))
    parser.add_argument("--pairs", type=int, default=40, help="per category and generator")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--budget-ms", type=float, default=100.0, help="the whole alignment's")
    parser.add_argument(
        "--ensemble",
        type=int,
        default=None,
        help="runs fused into each cloud's pose (default: the alignment's)",
    )
    parser.add_argument("--schedule", choices=("on", "off"), default=None,
                        help="each pose on its card's schedule or on every step (default: as "
                        "itnet-align asks)")  # fmt: skip
    parser.add_argument("--candidates", type=int, default=6, help="rivals judged a pair")
    parser.add_argument("--finalists", type=int, default=3, help="rivals ICP finishes")
    parser.add_argument("--records", type=Path, default=ROOT / "runs/align_calibration.json",
                        help="the collected evidence (read back with --from-records)")  # fmt: skip
    parser.add_argument("--refine", choices=("on", "off", "both"), default="on",
                        help="judge the candidates refined by ICP (on), as without open3d "
                        "(off), or both, every pair each way")  # fmt: skip
    parser.add_argument("--from-records", action="store_true")
    parser.add_argument("--write", type=Path, default=None, help="write the fitted calibration")
    parser.add_argument("--json", type=Path, default=None, help="write the replay's numbers")
    args = parser.parse_args()

    if args.from_records:
        records = json.loads(args.records.read_text())
    else:
        catalog = Catalog.load()
        records = []
        modes = {"on": (True,), "off": (False,), "both": (True, False)}[args.refine]
        for category, generator, refine in product(args.categories, args.generators, modes):
            start = time.perf_counter()
            got = collect(catalog, category, generator, args.pairs, args.seed, args.data,
                          args.budget_ms, args.ensemble, args.candidates, args.finalists,
                          refine, None if args.schedule is None else args.schedule == "on")  # fmt: skip
            records += got
            right = np.mean([r["right"][0] for r in got])
            print(f"{category:8s} {_group(got[0]):20s} {len(got)} pairs, composed right "
                  f"{right:.1%}, {time.perf_counter() - start:.0f} s", flush=True)  # fmt: skip
        args.records.parent.mkdir(parents=True, exist_ok=True)
        args.records.write_text(json.dumps(records))

    rows = np.array([row for r in records for row in r["rows"]])
    labels = np.array([y for r in records for y in r["right"]])
    weights = fit_logistic(rows, labels)
    fitted = Calibration(weights, f"{len(records)} validation pairs ({', '.join(args.categories)};"
                         f" {', '.join(args.generators)}), {len(rows)} candidates")  # fmt: skip
    print("weights:", dict(zip(FEATURES, np.round(weights, 3))))
    report: dict = {"pairs": len(records), "candidates": len(rows), "weights":
                    dict(zip(FEATURES, np.round(weights, 4).tolist())), "sure": {}}  # fmt: skip
    groups = sorted({_group(r) for r in records})
    for sure in SURE:
        out = replay(records, fitted, sure)
        line = {"all": _summary(out, np.ones(len(records), bool))}
        for g in groups:
            line[g] = _summary(out, np.array([_group(r) == g for r in records]))
        for c in sorted({r["category"] for r in records}):
            line[c] = _summary(out, np.array([r["category"] == c for r in records]))
        report["sure"][str(sure)] = line
        print(f"sure {sure:4.2f}: " + "; ".join(
            f"{k} {v['right']:.1%} vs {v['composed']:.1%} ({v['gain']:+.1%} ± {v['se']:.1%}), "
            f"rivals {v['rivals']:.0%}" for k, v in line.items() if k in ("all", *groups)))  # fmt: skip
    out = replay(records, fitted, 0.9)
    report["reliability"] = [
        {
            **row,
            "mean_probability": round(row["mean_probability"], 3),
            "right": round(row["right"], 3),
        }
        for row in reliability(out["probability"], out["right"])
    ]
    for row in report["reliability"]:
        print(row)
    if args.write is not None:
        fitted.write(args.write, command="python -m benchmarks.align_calibrate "
                     f"--pairs {args.pairs} --seed {args.seed}")  # fmt: skip
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n")


def _group(record: dict) -> str:
    """A pair's generator, and ``--no-refine`` where its candidates were judged without ICP."""
    return record["generator"] + ("" if record.get("refine", True) else " --no-refine")


def _summary(out: dict, mask: np.ndarray) -> dict:
    paired = paired_accuracy(out["right"][mask], out["composed"][mask])
    return {"pairs": int(mask.sum()), "right": float(out["right"][mask].mean()),
            "composed": float(out["composed"][mask].mean()), "gain": paired["gain"] / 100,
            "se": paired["gain_stderr"] / 100,
            "rivals": float(out["rivals"][mask].mean())}  # fmt: skip


if __name__ == "__main__":
    main()
