"""The paper's ablation table at reduced scale on the chair: what the recipe depends on.

Trains one model per row from scratch, all with the same data, steps and seed, then measures each
on the chair test split at its own number of unrolled iterations and at 10:

* ``K = 1 .. 7`` unrolled iterations (identity init, stop-gradient: the paper's method);
* ``no init``: the last layer starts random (K = 5);
* ``no stop``: the gradient flows through the moved input too (K = 5).

No choice is made on these numbers (every row takes its last step), so they come from the test
split directly. One command reruns it and writes ``OUT/ablation.md`` and ``OUT/ablation.json``::

    itnet fit ablation --steps 600 --out runs/ablation
"""

from __future__ import annotations

import json
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

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


class Ablation(BaseModel):
    """How the ablation is run: the data, where each row's run goes, and the training size."""

    model_config = ConfigDict(extra="forbid")

    data: Path = Field(default=Path("../shared/data/modelnet10"), description="ModelNet10 root")
    out: Path = Field(default=Path("runs/ablation"), description="the rows' runs and the table")
    cache: Path = Field(default=Path("cache"), description="the views' cache")
    steps: int = Field(default=600, ge=1, description="training steps per row")
    batch: int = Field(default=32, ge=2, description="clouds a training step")
    views: int = Field(default=2, ge=1, description="test views per chair")
    threads: int = Field(default=0, ge=0, description="torch threads (0: torch's default)")
    rows: str | None = Field(
        default=None, description="row names to run, comma-separated (default: all)"
    )


def run_row(name: str, overrides: dict, args: Ablation) -> dict:
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


def run_ablation(config: Ablation) -> list[dict]:
    """Train and measure every row asked for; write ``OUT/ablation.json`` and ``OUT/ablation.md``
    and return the rows."""
    asked = None if config.rows is None else set(config.rows.split(","))
    rows = [r for r in ROWS if asked is None or r[0] in asked]
    results = [run_row(name, overrides, config) for name, overrides in rows]
    config.out.mkdir(parents=True, exist_ok=True)
    (config.out / "ablation.json").write_text(json.dumps(results, indent=1))
    (config.out / "ablation.md").write_text(table(results, config.steps))
    return results
