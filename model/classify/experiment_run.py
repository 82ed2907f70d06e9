"""The transformer table from ``ClassifyExperimentConfig``: every row trained with the same
budget (``experiment.run_table``; finished rows are skipped), then the report written
(``report.write_report``).

    report = run_experiment(ClassifyExperimentConfig(steps=300, docs=Path("docs")))
    report.written                           # [docs/classification.md, ...]
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from itnet.model.classify.configs import ClassifyExperimentConfig
from itnet.model.classify.experiment import ORDER, run_table
from itnet.model.classify.report import write_report
from itnet.model.classify.train import ClassifyConfig

SHARED = (
    "data", "cache", "steps", "batch", "points", "decay_every", "eval_every", "test_views",
    "threads", "seed", "compile",
)  # fmt: skip
"""The fields every row's ``ClassifyConfig`` takes from the experiment's config."""


@dataclass(frozen=True)
class ClassifyExperimentReport:
    """The rows trained now or before ({variant: result.json}; empty: only the report was
    rewritten) and the report's files (empty: no ``docs``)."""

    rows: dict[str, dict[str, Any]] = field(default_factory=dict)
    written: list[Path] = field(default_factory=list)


def base_config(config: ClassifyExperimentConfig) -> ClassifyConfig:
    """The budget every row of the table trains with."""
    return ClassifyConfig(**{name: getattr(config, name) for name in SHARED})


def run_experiment(config: ClassifyExperimentConfig) -> ClassifyExperimentReport:
    """Train (or resume, or skip) every row of the table into ``config.out`` unless
    ``report_only``, then write the report into ``config.docs`` (None: none)."""
    rows = {} if config.report_only else run_table(base_config(config), config.out, ORDER)
    written = [] if config.docs is None else write_report(config.out, config.docs)
    return ClassifyExperimentReport(rows, written)
