"""Two runs of the scenes benchmark on the same scenes, compared object by object.

    python -m benchmarks.bench_scene --split validation --scenes 60 --budget-ms 3000 --out A.json
    python -m benchmarks.bench_scene --split validation --scenes 60 --budget-ms 3000 ... --out B.json
    python -m benchmarks.compare_scenes A.json B.json

The two runs must draw the same scenes (the same split, seed, count and kind): each visible object
is one row in both (``scene`` and ``object`` name it), so the differences are paired. Per frame
size: right (category and pose), found and named, first -> second with the paired gain and its
standard error; the false answers (named objects that match none, and things of no category
named) and the unknown answers that match no object, as counts.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench_scene import false_answers
from itnet.metrics import paired_accuracy

SIZES = {"rows": "320x240", "rows_640x480": "640x480"}


def _objects(rows: list[dict]) -> dict[tuple[int, int], dict]:
    return {(r["scene"], r["object"]): r for r in rows if r["kind"] == "object" and r["visible"]}


def compare(first: list[dict], second: list[dict]) -> dict[str, Any]:
    """Two runs' rows of one frame size -> {objects, right, found, named: {first, second, gain,
    gain_stderr} (percent), false and unknown: [first, second]}. Raises ValueError where the
    runs' objects differ (other scenes)."""
    a, b = _objects(first), _objects(second)
    if a.keys() != b.keys():
        raise ValueError("the two runs hold other objects: run both on the same scenes")
    keys = sorted(a)
    out: dict[str, Any] = {"objects": len(keys)}
    measures = {
        "right": lambda r: bool(r["right"]),
        "found": lambda r: bool(r["found"]),
        "named": lambda r: r.get("predicted") == r["category"],
    }
    for name, of in measures.items():
        x = np.array([of(a[k]) for k in keys], dtype=float)
        paired = paired_accuracy([of(b[k]) for k in keys], x)
        out[name] = {"first": round(100 * float(x.mean()), 1), "second": paired["accuracy"],
                     "gain": paired["gain"], "gain_stderr": paired["gain_stderr"]}  # fmt: skip
    out["false"] = [false_answers(first), false_answers(second)]
    out["unknown"] = [sum(r["kind"] == "unknown" for r in rows) for rows in (first, second)]
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path, help="bench_scene --out of the first run")
    parser.add_argument("second", type=Path, help="... and of the second, on the same scenes")
    args = parser.parse_args(argv)
    runs = [json.loads(p.read_text()) for p in (args.first, args.second)]
    for key, size in SIZES.items():
        if not runs[0].get(key) or not runs[1].get(key):
            continue
        try:
            c = compare(runs[0][key], runs[1][key])
        except ValueError as err:
            parser.error(f"{size}: {err}")
        cells = [f"{m} {c[m]['first']}% -> {c[m]['second']}% ({c[m]['gain']:+.1f} ± "
                 f"{c[m]['gain_stderr']:.1f})" for m in ("right", "found", "named")]  # fmt: skip
        print(f"{size}, {c['objects']} objects: " + ", ".join(cells)
              + f"; false {c['false'][0]} -> {c['false'][1]}, unknown {c['unknown'][0]} -> "
              f"{c['unknown'][1]}")  # fmt: skip


if __name__ == "__main__":
    main()
