"""The alignment benchmark's outputs: a markdown table and a figure like the paper's alignment
figure (CDFs of rotation and translation error, and the time per pair)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.metrics import ROTATION_THRESHOLD_DEG, TRANSLATION_THRESHOLD, paired_accuracy


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


RELIABILITY_BINS = (0.0, 0.3, 0.5, 0.7, 0.8, 0.9, 0.95, 1.0)


def reliability(probabilities: NDArray, right: NDArray) -> list[dict]:
    """Of the answers given each probability (RELIABILITY_BINS), how many were right: is the
    probability calibrated? -> a row per bin that holds any."""
    rows = []
    for lo, hi in zip(RELIABILITY_BINS[:-1], RELIABILITY_BINS[1:]):
        inside = (probabilities >= lo) & ((probabilities < hi) | (hi == 1.0))
        if inside.any():
            rows.append({"from": lo, "to": hi, "pairs": int(inside.sum()),
                         "mean_probability": float(probabilities[inside].mean()),
                         "right": float(right[inside].mean())})  # fmt: skip
    return rows


def reliability_table(outcome) -> list[str]:  # type: ignore[no-untyped-def]
    """``reliability`` of an itnet-align Outcome as markdown lines ([] without probabilities)."""
    prob = np.array([i.get("probability", np.nan) for i in outcome.info])
    if np.isnan(prob).all():
        return []
    lines = ["| probability | pairs | mean probability | right |", "|---|---|---|---|"]
    for row in reliability(prob, outcome.success()):
        lines.append(f"| {row['from']:.2f}–{row['to']:.2f} | {row['pairs']} | "
                     f"{row['mean_probability']:.2f} | {row['right']:.0%} |")  # fmt: skip
    return lines


def hypothesis_counts(outcome) -> str:  # type: ignore[no-untyped-def]
    """How often each hypothesis kind was chosen, e.g. 'itnet+icp 81, itnet+yaw180+icp 19'
    (whichever IT-Net runs it came from: 'itnet a1 b0+yaw90' counts as 'itnet+yaw90')."""
    names = [re.sub(r" a\d+ b\d+", "", i.get("hypothesis", "?")) for i in outcome.info]
    kinds, counts = np.unique(names, return_counts=True)
    order = np.argsort(-counts)
    return ", ".join(f"{kinds[i]} {counts[i]}" for i in order)


def time_split(results: dict) -> list[str]:
    """Markdown lines: where the time of each itnet variant goes (medians per pair)."""
    rows = []
    for name, outcome in results.items():
        if outcome.info and "itnet_ms" in outcome.info[0]:
            part = {k: np.median([i.get(k, 0.0) for i in outcome.info])
                    for k in ("itnet_ms", "composed_ms", "rivals_ms", "iterations")}  # fmt: skip
            doubt = np.mean([i.get("considered", 0) > 0 for i in outcome.info])
            rows.append(f"| {name} | {part['itnet_ms']:.1f} ms | {part['composed_ms']:.1f} ms | "
                        f"{part['rivals_ms']:.1f} ms | {part['iterations']:.0f} | {doubt:.0%} |")  # fmt: skip
    if not rows:
        return []
    return ["", "Where the time goes (medians per pair):", "",
            "| method | both poses (together) | composed pose: ICP, judging | rivals | IT-Net "
            "iterations | pairs in doubt (rivals judged) |", "|---|---|---|---|---|---|", *rows]  # fmt: skip


def _subset(outcome, keep: np.ndarray):  # type: ignore[no-untyped-def]
    """The Outcome of the pairs ``keep`` (bool, one a pair)."""
    picked = type(outcome)()
    for name in ("rotation_deg", "translation", "ms", "info", "generator"):
        values = getattr(outcome, name)
        setattr(picked, name, [v for v, k in zip(values, keep) if k])
    return picked


def paired_line(results: dict, name: str, reference: str) -> str:
    """'+x.x ± s.e. points' of ``name`` over ``reference`` on the same pairs
    (``itnet.metrics.paired_accuracy``)."""
    a, b = results[name].success(), results[reference].success()
    if len(a) != len(b) or len(a) < 2:
        return "–"
    paired = paired_accuracy(a, b)
    return f"{paired['gain']:+.1f} ± {paired['gain_stderr']:.1f} points"


def method_rows(results: dict) -> list[str]:
    rows = [
        "| method | success (10°, 0.1 r) | median rotation error | median translation error "
        "| median time per pair | pairs |",
        "|---|---|---|---|---|---|",
    ]
    for name, outcome in results.items():
        s = summary(outcome)
        rows.append(
            f"| {name} | **{s['success']:.1%}** | {s['median_rotation_deg']:.1f}° | "
            f"{s['median_translation']:.3f} r | {s['median_ms']:.1f} ms | {s['pairs']} |"
        )
    return rows


def write_report(results: dict, meta: dict, stem: Path) -> None:
    """Write ``stem``.md (a table per pair generator, the paired comparison with the composed
    poses, the reliability of the probability, setup, command) and ``stem``.png (figure)."""
    lines = [
        f"# Alignment benchmark: itnet-align ({meta.get('category', 'chair')})",
        "",
        f"Made by `{meta['command']}` (writes this file, `align_benchmark.png` and "
        "`align_benchmark.json`).",
    ]
    generators = meta.get("generators") or ["any_view"]
    reference = next((n for n in results if n.startswith("composed poses")), None)
    for generator in generators:
        part = {name: _subset(o, np.array([g == generator for g in o.generator]))
                for name, o in results.items() if generator in o.generator}  # fmt: skip
        if not part:
            continue
        lines += ["", f"## Pairs: `{generator}`", "", *method_rows(part)]
        if reference is not None:
            lines.append("")
            for name in part:
                if name.startswith("itnet-align") and len(part[name].ms) == len(part[reference].ms):
                    lines.append(f"- `{name}` against the {reference}, paired: "
                                 f"{paired_line(part, name, reference)}")  # fmt: skip
    lines += [
        "",
        "## Setup",
        "",
        f"- Pairs: {meta['pairs']} pairs of partial scans of the same object, ModelNet10 "
        f"{meta['split']} shapes of the category (`{meta['data']}`), seed {meta['seed']} "
        f"(`benchmarks.align_pairs`); median {meta['points'][0]} / {meta['points'][1]} points "
        "in A / B"
        + (
            f"; every scan by the `{meta['sensor']}` camera's model, the object at its real size."
            if meta.get("sensor")
            else "."
        ),
        "- Success: rotation error < 10° and A's centroid within 0.1 object radii of where the "
        "true T_b_from_a puts it, the best of the category's symmetric equivalents "
        "(`itnet.metrics.alignment_errors`).",
        f"- Model: {meta['model']}; budget {meta['budget_ms']:g} ms for the whole alignment.",
        "- Sizes for every method (voxels, ICP distances) are fractions of B's RMS radius, "
        "measured on the cloud; all global baselines end with the same point-to-plane ICP as "
        "`itnet-align --refine`.",
        "- Times: wall clock per pair on this machine (2 CPU cores), after one warm-up call per "
        "method; the methods take turns pair by pair, so a change in load hits them alike.",
        *[f"- {note}" for note in meta.get("notes", [])],
    ]
    lines += time_split(results)
    for name, outcome in results.items():
        table = reliability_table(outcome)
        if table and name.startswith("itnet-align"):
            lines += ["", f"`{name}`, all pairs: chosen hypotheses: "
                      f"{hypothesis_counts(outcome)}.", "", *table]  # fmt: skip
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
