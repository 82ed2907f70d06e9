"""The paper's classification table on partial ModelNet10: every row trained with the same
budget, one after the other (each resumable), then the report.

``run_table`` trains the rows that have no ``result.json`` yet; ``itnet classify-experiment``
calls it, then writes ``docs/classification.md`` (+ .json) and ``docs/confusion.png``
(``itnet.model.classify.report``).
"""

from __future__ import annotations

from pathlib import Path

from itnet.model.classify.network import VARIANTS
from itnet.model.classify.train import ClassifyConfig, train

ORDER = ("itnet-2", "none", "itnet-1", "tnet-1", "tnet-reg-1", "tnet-reg-2", "tnet-2")
"""Training order: the product's candidate first, so an interrupted table still has it."""


def row_config(base: ClassifyConfig, variant: str, out: Path) -> ClassifyConfig:
    """The run of one row: the same budget as every other row, its own folder."""
    return base.model_copy(update={"variant": variant, "out": out / variant})


def run_table(
    base: ClassifyConfig, out: Path, variants: tuple[str, ...] = ORDER, progress: bool = True
) -> dict[str, dict]:
    """Train (or resume, or skip when finished) each variant -> {variant: result.json}."""
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        raise ValueError(f"unknown variants {unknown}; known: {list(VARIANTS)}")
    return {v: train(row_config(base, v, out), log_progress=progress) for v in variants}
