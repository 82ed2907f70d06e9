"""The paper's ablation table at reduced scale on the chair: what the recipe depends on.

Trains one model per row from scratch, all with the same data, steps and seed, then measures each
on the chair test split at its own number of unrolled iterations and at 10:

* ``K = 1 .. 7`` unrolled iterations (identity init, stop-gradient: the paper's method);
* ``no init``: the last layer starts random (K = 5);
* ``no stop``: the gradient flows through the moved input too (K = 5).

No choice is made on these numbers (every row takes its last step), so they come from the test
split directly. One command reruns it and writes ``OUT/ablation.md`` and ``OUT/ablation.json``::

    python -m itnet.model.ablation --steps 600 --out runs/ablation
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

PAPER = {  # Yuan et al., ICCV 2019, cars, accuracy % for 1-7 unrolled iterations
    "ours": [36.9, 41.7, 47.7, 61.1, 67.6, 62.6, 48.2],
    "no init": [17.1, 0.5, 18.4, 7.3, 6.2, 41.1, 13.1],
    "no stop": [36.0, 5.0, 0.0, 0.0, 4.1, 4.1, 0.0],
}
ROWS: list[tuple[str, dict]] = [
    *((f"K={k}", {"iterations": k}) for k in range(1, 8)),
    ("no init (K=5)", {"iterations": 5, "identity_init": False}),
    ("no stop (K=5)", {"iterations": 5, "stop_gradient": False}),
]


def run_row(name: str, overrides: dict, args: argparse.Namespace) -> dict:
    """Train one row (resumable: its own run folder) and measure it on the test split."""
    import numpy as np

    from itnet.model.categories import category
    from itnet.model.category_set import test_scans
    from itnet.model.evaluate import anytime_poses, report, torch_step
    from itnet.model.scanner import scan_config
    from itnet.model.train import TrainConfig, load_checkpoint, train

    slug = name.split(" (")[0].replace(" ", "_").replace("=", "")
    config = TrainConfig(
        data=args.data,
        out=args.out / slug,
        cache=args.cache,
        steps=args.steps,
        batch=args.batch,
        decay_every=max(1, args.steps // 4),
        bn_decay_every=max(1, args.steps // 4),
        eval_every=args.steps,
        threads=args.threads,
        **overrides,
    )
    train(config, resume=True, progress=False)
    net, _ = load_checkpoint(config.out / "last.pt")
    scans, _ = test_scans(args.data, category("chair"), args.views, 2024, scan_config(), args.cache)
    poses = anytime_poses(torch_step(net), scans, 10, config.points)
    rep = report(poses, scans)[0]
    k = overrides["iterations"]
    return {
        "row": name,
        "at_trained": round(100 * rep.accuracy[k], 1),
        "at_10": round(100 * rep.accuracy[10], 1),
        "scans": rep.scans,
        "stderr_at_10": round(
            100 * float(np.sqrt(rep.accuracy[10] * (1 - rep.accuracy[10]) / rep.scans)), 1
        ),
    }


def table(results: list[dict], steps: int) -> str:
    lines = [
        "| row | ours: accuracy % at its K | at 10 iterations | paper (cars, at K) |",
        "|---|---|---|---|",
    ]
    for r in results:
        k = int(r["row"].split("K=")[1].rstrip(")")) if "K=" in r["row"] else 5
        key = "no init" if "no init" in r["row"] else "no stop" if "no stop" in r["row"] else "ours"
        lines.append(
            f"| {r['row']} | {r['at_trained']} | {r['at_10']} ± {r['stderr_at_10']} | "
            f"{PAPER[key][k - 1]} |"
        )
    scans = results[0]["scans"] if results else 0
    return "\n".join(lines) + f"\n\n{steps} steps per row, {scans} occluded test scans of chairs.\n"


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data/modelnet10"))
    parser.add_argument("--out", type=Path, default=Path("runs/ablation"))
    parser.add_argument("--cache", type=Path, default=Path("cache"))
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--views", type=int, default=2, help="test views per chair")
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--rows", nargs="*", help="row names to run (default: all)")
    args = parser.parse_args(argv)
    rows = [r for r in ROWS if not args.rows or r[0] in args.rows]
    results = [run_row(name, overrides, args) for name, overrides in rows]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "ablation.json").write_text(json.dumps(results, indent=1))
    (args.out / "ablation.md").write_text(table(results, args.steps))
    print(table(results, args.steps))
    return results


if __name__ == "__main__":
    main()
