"""The classifier's build configs (``ClassifyTrainConfig``, ``ClassifyExperimentConfig``,
``SizePriorFitConfig``, ``ClassifierExportConfig``): their defaults are the commands' documented
ones, each command offers exactly their fields, a bad view rule, elevation or cascade is refused
with the command line's message, and the command line loads none of the heavy libraries."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import typer
from pydantic import BaseModel, ValidationError

from itnet.cli import app
from itnet.export.classifier_build_config import ClassifierExportConfig
from itnet.model.classify.configs import (
    ClassifyExperimentConfig,
    ClassifyTrainConfig,
    SizePriorFitConfig,
)

DATA = Path("../shared/data/modelnet10")
DOCUMENTED = {
    "classify-train": (ClassifyTrainConfig, {
        "variant": "itnet-2", "data": DATA, "out": Path("runs/cls-ship/itnet-2"), "steps": 3200,
        "lr": 5e-4, "decay_every": 800, "bn_momentum": 0.1, "init_from": None, "balanced": False,
        "up_weight": 0.0, "stretch": 1.0, "upright": None, "views": "occluded,paper",
        "elevation": None, "canonical_points": None, "label_smoothing": 0.0, "hold_test": False,
        "ema": None, "head": "pointnet", "neighbours": None, "transformer_from": None,
        "freeze_transformer": False, "init_seed": None, "eval_every": 200, "threads": 1,
        "compile": True, "cache": Path("cache"), "batch": 32, "device": "cpu", "data_workers": 0,
    }),
    "classify-experiment": (ClassifyExperimentConfig, {
        "data": DATA, "out": Path("runs/cls"), "steps": 1200, "batch": 32, "points": 256,
        "decay_every": 240, "eval_every": 200, "test_views": 4, "threads": 1, "compile": True,
        "seed": 0, "cache": Path("cache"), "docs": Path("docs"), "report_only": False,
    }),
    "classify-size-prior": (SizePriorFitConfig, {
        "classifier": Path("itnet/models/classifier.onnx"), "data": DATA, "views": 2, "df": 3.0,
        "weight": 0.5, "split": "val", "write": False, "cache": Path("cache"), "sizes": "inches",
        "rules": "occluded,paper",
    }),
    "classify-export": (ClassifierExportConfig, {
        "out": Path("itnet/models/classifier.onnx"), "points": None, "canonical_points": None,
        "int8": False, "target": 0.95, "report": None, "confusion": None, "weights_out": None,
        "fuse_with": [], "cascade": None, "beside": Path("itnet/models/classifier.onnx"),
    }),
}  # fmt: skip


@pytest.mark.parametrize("name", DOCUMENTED)
def test_each_config_holds_the_command_defaults_and_the_command_offers_its_fields(
    name: str,
) -> None:
    kind, documented = DOCUMENTED[name]
    config: BaseModel = kind()
    assert config.model_dump() == documented
    command = typer.main.get_command(app).commands[name]  # type: ignore[attr-defined]
    options = {p.name: p.default for p in command.params if p.param_type_name == "option"}
    options.pop("help", None)
    assert options.keys() == documented.keys()
    for field, default in documented.items():
        given = options[field]
        assert (Path(given) if isinstance(default, Path) else given) == default, field


@pytest.mark.parametrize(
    ("kind", "values", "field", "message"),
    [
        (ClassifyTrainConfig, {"views": "sideways"}, "views", "unknown view rule 'sideways'"),
        (ClassifyTrainConfig, {"views": " , "}, "views", "unknown view rule ''"),
        (ClassifyTrainConfig, {"views": "paper+kinect_v9"}, "views", "unknown sensor 'kinect_v9'"),
        (ClassifyTrainConfig, {"elevation": "ten"}, "elevation", "two numbers, MIN,MAX"),
        (ClassifyTrainConfig, {"elevation": "50,10"}, "elevation", "degrees with -90 < MIN"),
        (ClassifyTrainConfig, {"elevation": "0,90"}, "elevation", "degrees with -90 < MIN"),
        (SizePriorFitConfig, {"rules": "paper,sideways"}, "rules", "unknown view rule 'sideways'"),
        (SizePriorFitConfig, {"sizes": "feet"}, "sizes", "Input should be 'inches' or 'real'"),
        (ClassifierExportConfig, {"cascade": 0.8}, "cascade", "needs heads to cascade to"),
        (
            ClassifierExportConfig,
            {"cascade": 0.8, "fuse_with": [Path("a.pt")], "int8": True},
            "cascade",
            "is for float32 graphs (not with --int8)",
        ),
    ],
)
def test_a_bad_value_is_refused_with_the_command_line_message(
    kind: type[BaseModel], values: dict, field: str, message: str
) -> None:
    with pytest.raises(ValidationError) as refused:
        kind(**values)
    error = refused.value.errors(include_url=False)[0]
    assert error["loc"] == (field,) and error["msg"].startswith(message), error


def test_the_command_names_the_option_it_refuses() -> None:
    from typer.testing import CliRunner

    run = CliRunner().invoke(app, ["classify-train", "--elevation", "0,90", "--steps", "1"])
    assert run.exit_code == 2
    assert "error: --elevation: degrees with -90 < MIN <= MAX < 90" in run.output


def test_text_options_parse_into_the_run() -> None:
    from itnet.model.classify.experiment_run import base_config
    from itnet.model.classify.train_run import classify_config

    given = ClassifyTrainConfig(views=" surface, occluded+kinect_v2 ", elevation="-10,55",
                                bn_momentum=0.3, head="local", neighbours=8)  # fmt: skip
    assert given.view_rules() == ("surface", "occluded+kinect_v2")
    run = classify_config(given)
    assert run.views == ("surface", "occluded+kinect_v2") and run.elevation == (-10.0, 55.0)
    assert run.bn_momentum == (0.3, 0.01) and run.out == Path("runs/cls-ship/itnet-2")
    assert (run.head, run.neighbours, run.compile, run.steps) == ("local", 8, True, 3200)
    assert classify_config(ClassifyTrainConfig()).elevation is None
    base = base_config(ClassifyExperimentConfig(steps=300, seed=2))
    assert (base.steps, base.seed, base.decay_every, base.compile) == (300, 2, 240, True)


def test_the_command_line_starts_without_torch_onnx_or_open3d() -> None:
    code = (
        "import sys, itnet.cli; "
        "print(sorted({'torch', 'onnx', 'open3d', 'matplotlib'} & set(sys.modules)))"
    )
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert loaded.returncode == 0 and loaded.stdout.strip() == "[]", loaded.stdout + loaded.stderr
