"""The alignment benchmark's outputs: a markdown table and a figure like the paper's alignment
figure (CDFs of rotation and translation error, and the time per pair)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from itnet.metrics import ROTATION_THRESHOLD_DEG, TRANSLATION_THRESHOLD


def summary(outcome) -> dict:  # type: ignore[no-untyped-def]
    """Success rate, median errors and median time of one method's Outcome."""
    ok = outcome.success()
    return {
        "pairs": len(ok),
        "success": float(ok.mean()),
        "median_rotation_deg": float(np.median(outcome.rotation_deg)),
        "median_translation": float(np.median(outcome.translation)),
        "median_ms": float(np.median(outcome.ms)),
    }


def confidence_table(outcome) -> list[str]:  # type: ignore[no-untyped-def]
    """Success rate by reported confidence (is the confidence worth reading?)."""
    conf = np.array([i.get("confidence", np.nan) for i in outcome.info])
    if np.isnan(conf).all():
        return []
    ok = outcome.success()
    rows = ["| confidence | pairs | success |", "|---|---|---|"]
    for lo, hi in ((0.0, 0.3), (0.3, 0.6), (0.6, 1.01)):
        sel = (conf >= lo) & (conf < hi)
        rate = f"{ok[sel].mean():.0%}" if sel.any() else "–"
        rows.append(f"| {lo:.1f}–{min(hi, 1.0):.1f} | {int(sel.sum())} | {rate} |")
    return rows


def hypothesis_counts(outcome) -> str:  # type: ignore[no-untyped-def]
    """How often each hypothesis kind was chosen, e.g. 'itnet+icp 81, itnet+yaw180+icp 19'
    (whichever IT-Net runs it came from: 'itnet a1 b0+yaw90' counts as 'itnet+yaw90')."""
    names = [re.sub(r" a\d+ b\d+", "", i.get("hypothesis", "?")) for i in outcome.info]
    kinds, counts = np.unique(names, return_counts=True)
    order = np.argsort(-counts)
    return ", ".join(f"{kinds[i]} {counts[i]}" for i in order)


def time_split(results: dict) -> list[str]:
    """Markdown lines: where the time of each itnet-align variant goes (medians per pair)."""
    rows = []
    for name, outcome in results.items():
        if name.startswith("itnet-align") and outcome.info and "itnet_ms" in outcome.info[0]:
            part = {k: np.median([i.get(k, 0.0) for i in outcome.info])
                    for k in ("itnet_ms", "rank_ms", "refine_ms", "score_ms", "iterations",
                              "considered")}  # fmt: skip
            rows.append(f"| {name} | {part['itnet_ms']:.1f} ms | {part['rank_ms']:.1f} ms | "
                        f"{part['refine_ms']:.1f} ms | {part['score_ms']:.1f} ms | "
                        f"{part['iterations']:.0f} | {part['considered']:.0f} |")  # fmt: skip
    if not rows:
        return []
    return ["", "Where the time of itnet-align goes (medians per pair):", "",
            "| method | IT-Net (both clouds) | ranking | ICP | scoring | IT-Net iterations "
            "| hypotheses |", "|---|---|---|---|---|---|---|", *rows]  # fmt: skip


def write_report(results: dict, meta: dict, stem: Path) -> None:
    """Write ``stem``.md (table, setup, command) and ``stem``.png (figure)."""
    rows = [
        "| method | success (10°, 0.1 r) | median rotation error | median translation error "
        "| median time per pair | pairs |",
        "|---|---|---|---|---|---|",
    ]
    for name, outcome in results.items():
        s = summary(outcome)
        rows.append(
            f"| {name} | **{s['success']:.0%}** | {s['median_rotation_deg']:.1f}° | "
            f"{s['median_translation']:.3f} r | {s['median_ms']:.1f} ms | {s['pairs']} |"
        )
    lines = [
        "# Alignment benchmark: itnet-align vs. registration baselines",
        "",
        f"Made by `{meta['command']}` (writes this file, `align_benchmark.png` and "
        "`align_benchmark.json`).",
        "",
        *rows,
        "",
        f"- Pairs: {meta['pairs']} pairs of partial scans of the same object, ModelNet10 *test* "
        f"chairs (`{meta['data']}`, held out from training), two independent random viewpoints "
        "each (full SO(3), `itnet.model.scanner` z-buffer scans with sensor noise), seed "
        f"{meta['seed']}; median {meta['points'][0]} / {meta['points'][1]} points in A / B.",
        "- Success: rotation error < 10° and A's centroid within 0.1 object radii of where the "
        "true T_b_from_a puts it (`itnet.metrics.alignment_errors`).",
        f"- Model: {meta['model']}; IT-Net budget {meta['budget_ms']:g} ms per pose "
        "(the model's recommended iteration count ends it first).",
        "- Sizes for every method (voxels, ICP distances) are fractions of B's RMS radius, "
        "measured on the cloud; all global baselines end with the same point-to-plane ICP as "
        "`itnet-align --refine`.",
        "- Times: wall clock per pair on this machine (2 CPU cores, shared with other jobs), "
        "after one warm-up call per method; the methods take turns pair by pair, so a change "
        "in load hits them alike.",
        *[f"- {note}" for note in meta.get("notes", [])],
    ]
    lines += time_split(results)
    for name, outcome in results.items():
        table = confidence_table(outcome)
        if table and name.startswith("itnet-align"):
            lines += ["", f"`{name}`: chosen hypotheses: {hypothesis_counts(outcome)}.", "", *table]
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    plot(results, stem.with_suffix(".png"))


def plot(results: dict, path: Path) -> None:
    """CDF of rotation error, CDF of translation error, bar of median time per pair."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8), gridspec_kw={"width_ratios": [1, 1, 1.1]})
    for name, outcome in results.items():
        style = "-" if name.startswith("itnet") else "--"
        for ax, values in zip(axes[:2], (outcome.rotation_deg, outcome.translation), strict=True):
            x = np.sort(values)
            ax.step(x, np.arange(1, len(x) + 1) / len(x), style, where="post", label=name)
    axes[0].axvline(ROTATION_THRESHOLD_DEG, color="grey", lw=0.8)
    axes[0].set(xlabel="rotation error (deg)", ylabel="fraction of pairs", xlim=(0, 180),
                title="rotation error CDF")  # fmt: skip
    axes[1].axvline(TRANSLATION_THRESHOLD, color="grey", lw=0.8)
    axes[1].set(xlabel="translation error (object radii)", xlim=(0, 1.0),
                title="translation error CDF")  # fmt: skip
    for ax in axes[:2]:
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
    names = list(results)
    times = [float(np.median(results[n].ms)) for n in names]
    success = [float(results[n].success().mean()) for n in names]
    bars = axes[2].barh(names, times, color=[f"C{i % 10}" for i in range(len(names))])
    for bar, rate, ms in zip(bars, success, times, strict=True):
        axes[2].text(bar.get_width() + 0.01 * max(times), bar.get_y() + bar.get_height() / 2,
                     f"{ms:.0f} ms, {rate:.0%} ok", va="center", fontsize=8)  # fmt: skip
    axes[2].set(xlim=(0, 1.35 * max(times)), xlabel="median time per pair (ms)",
                title="time per pair (and success)")  # fmt: skip
    axes[2].invert_yaxis()
    axes[2].tick_params(axis="y", labelsize=8)
    axes[0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
