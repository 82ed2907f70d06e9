"""``build``: a category's pose model rebuilt from its data to its shipped files, a plan of stages.

    report = build(BuildConfig(category="table", steps=3000))
    report.model, report.verifier          # runs/build/table/model/table.onnx, ...-verifier.onnx

Each stage has one interface (``BuildStage``): it is done where its output exists, so a build
that stopped goes on from the first stage not done (the training itself resumes from its last
checkpoint). In order:

    train      the pose network fine-tuned from earlier weights (upright where the category needs
               up), the best validation checkpoint kept                       train/train.json
    evaluate   its anytime accuracy on the test split                         eval/report.json
    export     the int8 step graph with its card                              model/C.onnx
    verifier   the learned verifier trained on the model's runs, exported     model/C-verifier.onnx
    centre     the centre corrections fitted and written into the card        centre.json
    measure    the model as served (one run and the card's runs fused, with up where needed)
               on the test views                                              served.json
    card       the card's runs and measurements                               card.json
    compact    the weights stored as float16                                  compact.json

The files in ``model/`` are what ships: copy them into ``itnet/models/``, then refit the scene
files that name the models' graphs (``itnet fit scene-centre --only C``, docs/training.md).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Protocol

from itnet.model.build_config import BuildConfig

SCANNERS = ("occluded", "surface", "paper")


@dataclass(frozen=True)
class Build:
    """A build in progress: its config and the paths its stages share."""

    config: BuildConfig

    @property
    def folder(self) -> Path:
        return self.config.folder()

    @property
    def model(self) -> Path:
        return self.folder / "model" / f"{self.config.category}.onnx"

    @property
    def verifier(self) -> Path:
        return self.folder / "model" / f"{self.config.category}-verifier.onnx"

    @property
    def requires_up(self) -> bool:
        from itnet.model.categories import category

        return category(self.config.category).requires_up

    @property
    def up(self) -> float | None:
        """The up error the model is measured and served with (None: it needs no up)."""
        return self.config.up_error_deg if self.requires_up else None

    def checkpoint(self) -> Path:
        return Path(json.loads((self.folder / "train" / "train.json").read_text())["checkpoint"])


class BuildStage(Protocol):
    name: ClassVar[str]

    def output(self, build: Build) -> Path: ...
    def run(self, build: Build) -> None: ...


def _write(path: Path, record: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=1, default=str) + "\n")


class Train:
    name: ClassVar[str] = "train"

    def output(self, build: Build) -> Path:
        return build.folder / "train" / "train.json"

    def run(self, build: Build) -> None:
        from itnet.model.train_config import TrainOptions
        from itnet.model.train_run import train_run

        c = build.config
        options = TrainOptions(
            data=c.data, category=c.category, out=build.folder / "train", steps=c.steps,
            batch=c.batch, lr=c.lr, decay_every=c.decay_every, eval_every=c.eval_every,
            threads=c.threads, init_from=c.weights(), loss="distance", resume=True,
            compile=c.compile, upright=5.0 if build.requires_up else None, cache=c.cache,
        )  # fmt: skip
        report = train_run(options, progress=False)
        _write(self.output(build), {"checkpoint": report.checkpoint, "step": report.step,
                                    "val_accuracy": report.val_accuracy})  # fmt: skip


class Evaluate:
    name: ClassVar[str] = "evaluate"

    def output(self, build: Build) -> Path:
        return build.folder / "eval" / "report.json"

    def run(self, build: Build) -> None:
        from itnet.model.eval_config import EvalOptions
        from itnet.model.eval_run import evaluate_model

        c = build.config
        evaluate_model(EvalOptions(checkpoint=build.checkpoint(), data=c.data,
                                   category=c.category, views=c.views, out=build.folder / "eval",
                                   cache=c.cache, up=build.up))  # fmt: skip


class Export:
    name: ClassVar[str] = "export"

    def output(self, build: Build) -> Path:
        return build.model

    def run(self, build: Build) -> None:
        from itnet.export.checkpoint_export import export_checkpoint
        from itnet.export.export_config import ExportOptions

        options = ExportOptions(out=build.model, category=build.config.category,
                                report=Evaluate().output(build), int8=True)  # fmt: skip
        export_checkpoint(build.checkpoint(), options)


class Verifier:
    name: ClassVar[str] = "verifier"

    def output(self, build: Build) -> Path:
        return build.verifier

    def run(self, build: Build) -> None:
        from itnet.export.verifier_export import export_verifier
        from itnet.model.verifier import VerifierConfig, load_verifier, train_verifier
        from itnet.model_card import VerifierCard

        c = build.config
        config = VerifierConfig(category=c.category, pose_model=build.model,
                                steps=c.verifier_steps, views=c.verifier_views, data=c.data,
                                cache=c.cache, up_error_deg=build.up)  # fmt: skip
        trained_at = train_verifier(config, build.folder / "verifier", log=_silent)
        net, trained = load_verifier(trained_at)
        card = VerifierCard(name=f"{c.category}-verifier", category=c.category,
                            points=trained.points, trained_on=build.model.name,
                            training=trained.model_dump(mode="json"))  # fmt: skip
        export_verifier(net, card, build.verifier)


class Centre:
    name: ClassVar[str] = "centre"

    def output(self, build: Build) -> Path:
        return build.folder / "centre.json"

    def run(self, build: Build) -> None:
        from itnet.model.centre_fit_config import CentreFitOptions
        from itnet.model.centre_fit_run import fit_model_centre

        c = build.config
        options = CentreFitOptions(data=c.data, views=c.centre_views, write=True, cache=c.cache,
                                   up=build.up, report=self.output(build))  # fmt: skip
        fit_model_centre(build.model, options)


class Measure:
    name: ClassVar[str] = "measure"

    def output(self, build: Build) -> Path:
        return build.folder / "served.json"

    def run(self, build: Build) -> None:
        from itnet.model.served_accuracy import machine, measure

        c = build.config
        runs = sorted({1, c.runs})
        served = {
            scanner: measure(
                build.model,
                scanner,
                runs,
                c.budget_ms,
                c.views,
                c.cache,
                c.data,
                up_error_deg=build.up,
                log=_silent,
            )
            for scanner in SCANNERS
        }
        _write(self.output(build), {"machine": machine(), "model": build.model,
                                    "budget_ms": c.budget_ms, "split": "test", "views": c.views,
                                    "up_error_deg": build.up, **served})  # fmt: skip


class Card:
    name: ClassVar[str] = "card"

    def output(self, build: Build) -> Path:
        return build.folder / "card.json"

    def run(self, build: Build) -> None:
        from itnet.export.card_config import CardChanges
        from itnet.export.card_edit import edit_card

        served, runs = Measure().output(build), build.config.runs
        changes = CardChanges(
            recommended_ensemble=runs, ensemble_report=served if runs > 1 else None,
            up_report=served if build.requires_up else None,
            requires_up=True if build.requires_up else None,
        )  # fmt: skip
        report = edit_card(build.model, changes)
        _write(self.output(build), report.card.model_dump(mode="json"))


class Compact:
    name: ClassVar[str] = "compact"

    def output(self, build: Build) -> Path:
        return build.folder / "compact.json"

    def run(self, build: Build) -> None:
        from itnet.export.half_storage import store_half

        saved = {path.name: store_half(path) for path in (build.model, build.verifier)}
        _write(self.output(build), {"bytes_saved": saved})


def _silent(line: str) -> None:
    """A stage's own progress lines are left out: the build logs one line a stage, and each
    stage's files hold the rest (the training's and the verifier's log.jsonl)."""
    del line


STAGES: tuple[BuildStage, ...] = (
    Train(), Evaluate(), Export(), Verifier(), Centre(), Measure(), Card(), Compact(),
)  # fmt: skip


@dataclass(frozen=True)
class BuildReport:
    """What a build ran (the stages done before it were skipped) and the files it ships."""

    ran: list[str]
    skipped: list[str]
    model: Path
    verifier: Path


def build(config: BuildConfig, log: Callable[[str], None] = print) -> BuildReport:
    """Run every stage of ``config``'s build that is not done yet, in order; ``log`` gets a line
    per stage. Raises InputError for a category the registry does not know."""
    from itnet.model.categories import MODELNET10
    from itnet.model.input_error import InputError

    if config.category not in MODELNET10:
        raise InputError(f"unknown category {config.category!r} (known: {', '.join(MODELNET10)})")
    current = Build(config)
    ran, skipped = [], []
    for stage in STAGES:
        if stage.output(current).exists():
            skipped.append(stage.name)
            log(f"{stage.name}: done ({stage.output(current)})")
            continue
        log(f"{stage.name}: running")
        stage.run(current)
        ran.append(stage.name)
        log(f"{stage.name}: wrote {stage.output(current)}")
    return BuildReport(ran, skipped, current.model, current.verifier)
