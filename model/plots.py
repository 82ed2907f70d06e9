"""Evaluation plots: the anytime accuracy curve and the error CDFs (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.model.evaluate import AnytimeReport


def plot_anytime(
    rep: AnytimeReport,
    rotation_errors: NDArray,
    translation_errors: NDArray,
    trained_iterations: int,
    path: Path,
    title: str,
) -> Path:
    """Three panels: accuracy by iteration; CDF of rotation and of translation error at a few
    iteration counts. Errors are (S, K+1). Writes ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    ax = axes[0]
    ax.plot(rep.iterations, np.array(rep.accuracy) * 100, "o-", label="rot < 10° and trans < 0.1")
    ax.plot(rep.iterations, np.array(rep.rotation_accuracy) * 100, "--", label="rot < 10°")
    ax.plot(rep.iterations, np.array(rep.translation_accuracy) * 100, ":", label="trans < 0.1")
    ax.axvline(trained_iterations, color="grey", lw=0.8)
    ax.text(trained_iterations + 0.2, 3, "trained iterations", color="grey", fontsize=8)
    ax.set(xlabel="iterations", ylabel="accuracy (%)", ylim=(0, 100), title="anytime accuracy")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    last = len(rep.iterations) - 1
    shown = sorted({1, min(trained_iterations, last), min(10, last), last})
    for ax, errors, name, limit in (
        (axes[1], rotation_errors, "rotation error (°)", 180.0),
        (axes[2], translation_errors, "translation error (object radii)", 1.0),
    ):
        for k in shown:
            e = np.sort(errors[:, k])
            ax.plot(e, np.arange(1, len(e) + 1) / len(e) * 100, label=f"{k} iterations")
        ax.set(xlabel=name, ylabel="% of scans below", xlim=(0, limit), ylim=(0, 100))
        ax.set_xscale("symlog", linthresh=limit / 20)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[1].axvline(10, color="grey", lw=0.8)
    axes[2].axvline(0.1, color="grey", lw=0.8)
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_rotation_cdfs(errors: dict[str, NDArray], path: Path, title: str) -> Path:
    """One CDF of the final rotation error (degrees, (S,) each) per named option, on the same
    scans, with the 10° threshold marked. Writes ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for name, e in errors.items():
        e = np.sort(e)
        median = float(np.median(e))
        ax.plot(e, np.arange(1, len(e) + 1) / len(e) * 100, label=f"{name} (median {median:.1f}°)")
    ax.axvline(10, color="grey", lw=0.8)
    ax.set(xlabel="rotation error (°)", ylabel="% of scans below", xlim=(0, 30), ylim=(0, 100))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
