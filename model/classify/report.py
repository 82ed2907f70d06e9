"""The classification table's report: docs/classification.md (+ .json) and
docs/confusion_table.png (the best row's). The shipped graph's own confusion matrix,
docs/confusion.png, is plotted by ``itnet classify-export --confusion``.

Reads the finished rows' ``result.json`` (validation and test metrics of each row's best
validation checkpoint) under the experiment folder.
"""

from __future__ import annotations

import json
import platform
from pathlib import Path

import numpy as np

from itnet.model.classify.network import PAPER_ACCURACY, VARIANTS

LABELS = {
    "none": "none",
    "tnet-1": "T-Net, 1 iteration",
    "tnet-2": "T-Net, 2 iterations",
    "tnet-reg-1": "T-Net + regulariser, 1 iteration",
    "tnet-reg-2": "T-Net + regulariser, 2 iterations",
    "itnet-1": "IT-Net, 1 iteration",
    "itnet-2": "IT-Net, 2 iterations",
}


def finished_rows(out: Path) -> dict[str, dict]:
    """{variant: result.json} of the rows under ``out`` that finished, in the table's order."""
    rows = {}
    for variant in VARIANTS:
        path = out / variant / "result.json"
        if path.exists():
            rows[variant] = json.loads(path.read_text())
    return rows


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def table_markdown(rows: dict[str, dict]) -> str:
    """The table: test top-1 (± standard error), mean class accuracy, validation, the paper."""
    lines = [
        "| transformer | test top-1 % (± s.e.) | test mean class % | val top-1 % | best step | "
        "paper (Partial ModelNet40) % |",
        "|---|---|---|---|---|---|",
    ]
    for variant, r in rows.items():
        t = r["test"]
        lines.append(
            f"| {LABELS[variant]} | {_pct(t['accuracy'])} ± {_pct(t['standard_error'])} | "
            f"{_pct(t['mean_class_accuracy'])} | {_pct(r['val']['accuracy'])} | "
            f"{r['best_step']} / {r['steps']} | {PAPER_ACCURACY[variant]:.2f} |"
        )
    return "\n".join(lines)


def per_class_markdown(rows: dict[str, dict]) -> str:
    """Per-class test accuracy (%), one column per row."""
    classes = next(iter(rows.values()))["classes"]
    head = "| class | " + " | ".join(rows) + " |"
    lines = [head, "|---" * (len(rows) + 1) + "|"]
    for name in classes:
        cells = [_pct(r["test"]["per_class"].get(name, float("nan"))) for r in rows.values()]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_confusion(result: dict, path: Path, name: str | None = None) -> Path:
    """Row-normalised test confusion matrix of one row -> PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    confusion = np.array(result["test"]["confusion"], dtype=np.float64)
    share = confusion / np.maximum(confusion.sum(1, keepdims=True), 1)
    classes = result["classes"]
    fig, ax = plt.subplots(figsize=(7, 6))
    ax.imshow(share, cmap="Blues", vmin=0, vmax=1)
    for i in range(len(classes)):
        for j in range(len(classes)):
            if confusion[i, j]:
                color = "white" if share[i, j] > 0.5 else "black"
                ax.text(
                    j,
                    i,
                    f"{int(confusion[i, j])}",
                    ha="center",
                    va="center",
                    fontsize=7,
                    color=color,
                )
    ax.set_xticks(range(len(classes)), classes, rotation=45, ha="right")
    ax.set_yticks(range(len(classes)), classes)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true class")
    accuracy = 100 * result["test"]["accuracy"]
    ax.set_title(
        f"{name or LABELS[result['variant']]}: {result['test']['scans']} partial test views, "
        f"top-1 {accuracy:.1f}%"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(out: Path, docs: Path, trained: str | None = None) -> list[Path]:
    """docs/classification.json (the rows' results), the table and per-class markdown pasted
    into docs/classification.md between markers, and docs/confusion_table.png of the best row
    (by validation accuracy). ``trained``: where and how the rows were trained, said above the
    table (default: this machine, ``itnet classify-experiment``). Without finished rows under
    ``out``, the rows recorded in docs/classification.json stay. Returns the written paths."""
    rows = finished_rows(out)
    previous = docs / "classification.json"
    if not rows and previous.exists():  # the rows' runs are gone: keep the table as recorded
        recorded = json.loads(previous.read_text())
        rows, trained = recorded["rows"], trained or recorded.get("machine")
    if not rows:
        raise FileNotFoundError(f"{out}: no finished rows (result.json)")
    best = max(rows, key=lambda v: rows[v]["val"]["accuracy"])
    steps = sorted({r["steps"] for r in rows.values()})
    trained = trained or (
        f"{platform.machine()}, {platform.processor() or 'cpu'}, `itnet classify-experiment`, "
        f"{'/'.join(map(str, steps))} steps a row"
    )
    summary = {
        "machine": trained,
        "best_by_validation": best,
        "rows": {
            v: {k: r[k] for k in ("variant", "classes", "best_step", "steps", "val", "test")}
            for v, r in rows.items()
        },
        "paper": PAPER_ACCURACY,
    }
    docs.mkdir(parents=True, exist_ok=True)
    json_path = docs / "classification.json"
    json_path.write_text(json.dumps(summary, indent=1))
    png = plot_confusion(rows[best], docs / "confusion_table.png")
    generated = (
        "<!-- table: generated by `itnet classify-experiment` -->\n"
        + f"Trained on: {trained}.\n\n"
        + table_markdown(rows)
        + "\n\nPer-class test accuracy (%):\n\n"
        + per_class_markdown(rows)
        + "\n<!-- /table -->"
    )
    md = docs / "classification.md"
    text = (
        md.read_text()
        if md.exists()
        else "# Which object is it?\n\n<!-- table --><!-- /table -->\n"
    )
    start, end = text.find("<!-- table"), text.find("<!-- /table -->")
    if start < 0 or end < 0:
        text += "\n" + generated + "\n"
    else:
        text = text[:start] + generated + text[end + len("<!-- /table -->") :]
    md.write_text(text)
    return [json_path, md, png]
