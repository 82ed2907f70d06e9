"""Every category's evaluation in one table and one plot.

Reads the ``report.json`` files that ``itnet eval`` wrote for each category and scanner
(``EVALS/<category>/{occluded,paper}/report.json``, and ``surface/`` where it was measured) and
writes ``OUT/eval_categories.md`` (the README's table), ``OUT/eval_categories.json`` and
``OUT/anytime_categories.png`` (every category's anytime curve, one panel per kind of view)::

    itnet fit category-report runs/eval_categories docs
"""

from __future__ import annotations

import json
import math
from pathlib import Path

SCANNERS = ("occluded", "paper")  # every category has both
OPTIONAL_SCANNERS = ("surface",)  # shown where measured (views as a camera sees a mesh)
SHOWN_ITERATION = 10


def load_reports(evals: Path) -> dict[str, dict[str, dict]]:
    """{category: {scanner: report}} for every category folder holding both required scanners'
    reports (and the optional ones it has)."""
    out: dict[str, dict[str, dict]] = {}
    for folder in sorted(p for p in evals.iterdir() if p.is_dir()):
        reports = {s: folder / s / "report.json" for s in SCANNERS + OPTIONAL_SCANNERS}
        if all(reports[s].exists() for s in SCANNERS):
            out[folder.name] = {
                s: json.loads(p.read_text()) for s, p in reports.items() if p.exists()
            }
    return out


def _stderr_points(accuracy: float, scans: int) -> float:
    return 100 * math.sqrt(max(accuracy * (1 - accuracy), 1e-12) / scans)


def _accuracy_cell(report: dict | None, i: int) -> str:
    """'**acc** ± s.e.' (percent) at index ``i`` of a report; '–' where it was not measured."""
    if report is None:
        return "–"
    accuracy = report["accuracy"][i]
    return f"**{100 * accuracy:.1f}** ± {_stderr_points(accuracy, report['scans']):.1f}"


def table(reports: dict[str, dict[str, dict]], k: int = SHOWN_ITERATION) -> str:
    """Markdown: per category, accuracy at ``k`` iterations on every scanner (± one standard
    error), rotation/translation shares and median errors on occluded views, objects kept."""
    lines = [
        f"| category | symmetry | test objects (kept / turned / dropped) | scans | occluded views: "
        f"accuracy % at {k} | rot < 10° % | trans < 0.1 % | median rot ° | median trans (r) "
        f"| surface views: accuracy % at {k} | paper views: accuracy % at {k} | median rot ° |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, by in reports.items():
        occ, pap = by["occluded"], by["paper"]
        i = occ["iterations"].index(k)
        o = occ.get("orientation", {})
        kept = f"{o.get('kept', '?')} / {o.get('turned', '?')} / {o.get('dropped', '?')}"
        up = occ.get("up_error_deg")  # measured with the up direction given (held upright)
        shown = name if up is None else f"{name}, up given ({up:g}° off)"
        lines.append(
            f"| {shown} | {occ.get('symmetry', 'none')} | {kept} | {occ['scans']} | "
            f"{_accuracy_cell(occ, i)} | "
            f"{100 * occ['rotation_accuracy'][i]:.1f} | {100 * occ['translation_accuracy'][i]:.1f} | "
            f"{occ['median_rotation_deg'][i]:.1f} | {occ['median_translation'][i]:.3f} | "
            f"{_accuracy_cell(by.get('surface'), i)} | {_accuracy_cell(pap, i)} | "
            f"{pap['median_rotation_deg'][i]:.1f} |"
        )
    return "\n".join(lines) + "\n"


def plot(reports: dict[str, dict[str, dict]], path: Path) -> Path:
    """One panel per kind of view (occluded, surface where measured, paper): accuracy by
    iteration, one line per category."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = ["occluded"] + [s for s in OPTIONAL_SCANNERS if any(s in by for by in reports.values())]
    shown.append("paper")
    fig, axes = plt.subplots(1, len(shown), figsize=(6.5 * len(shown), 4.6), sharey=True)
    colours = plt.get_cmap("tab10")
    for ax, scanner in zip(axes, shown):
        for c, (name, by) in enumerate(reports.items()):
            if scanner not in by:
                continue
            rep = by[scanner]
            up = ", up given" if rep.get("up_error_deg") is not None else ""
            ax.plot(rep["iterations"], [100 * a for a in rep["accuracy"]], "o-", ms=2.5,
                    color=colours(c % 10),
                    label=f"{name} ({rep.get('symmetry', 'none')}{up})")  # fmt: skip
        ax.axvline(5, color="grey", lw=0.8)
        ax.text(5.2, 2, "trained iterations", color="grey", fontsize=8)
        ax.set(xlabel="iterations", title=f"{scanner} views", ylim=(0, 100))
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("accuracy at (10°, 0.1 r), %")
    axes[-1].legend(fontsize=8, loc="lower right")
    fig.suptitle("Anytime accuracy of every category (held-out ModelNet10 test objects)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(evals: Path, out: Path) -> str:
    """The per-category evaluations under ``evals`` (``<category>/{occluded,paper}/report.json``)
    -> ``OUT/eval_categories.md``, ``.json`` and the anytime plot; returns the table. ValueError
    where there is none."""
    reports = load_reports(evals)
    if not reports:
        raise ValueError(f"{evals}: no <category>/{{occluded,paper}}/report.json found")
    (out / "eval_categories.md").write_text(table(reports))
    (out / "eval_categories.json").write_text(json.dumps(reports, indent=1))
    plot(reports, out / "anytime_categories.png")
    return table(reports)
