"""The build commands' options are their configs' fields: every field an option of the same
name and default, and nothing else; ``train_config`` turns ``TrainOptions`` into the run's
``TrainConfig`` and refuses a bad choice by its option's name."""

from __future__ import annotations

from pathlib import Path

import pytest
import typer

from itnet.cli import app
from itnet.export.card_config import CardChanges
from itnet.export.export_config import ExportOptions
from itnet.model.centre_fit_config import CentreFitOptions
from itnet.model.eval_config import EvalOptions
from itnet.model.train_config import TrainOptions

COMMANDS = [
    ("train", TrainOptions, set()),
    ("eval", EvalOptions, set()),
    ("export", ExportOptions, {"checkpoint"}),
    ("card", CardChanges, {"model"}),
    ("centre-fit", CentreFitOptions, {"model"}),
]


@pytest.mark.parametrize(("name", "kind", "arguments"), COMMANDS, ids=[c[0] for c in COMMANDS])
def test_each_option_is_a_field_with_the_fields_default(name, kind, arguments) -> None:  # type: ignore[no-untyped-def]
    command = typer.main.get_command(app).commands[name]  # type: ignore[attr-defined]
    options = {p.name: p for p in command.params if p.param_type_name == "option"}
    assert set(options) == set(kind.model_fields)
    assert {p.name for p in command.params if p.param_type_name == "argument"} == arguments
    for field, spec in kind.model_fields.items():
        flag = "--" + field.replace("_", "-")
        assert flag in options[field].opts, (field, options[field].opts)
        default = options[field].default
        expected = spec.default
        assert (Path(default) if isinstance(expected, Path) else default) == expected, field
        assert spec.description, field  # the option's help


def test_train_options_become_the_runs_config() -> None:
    from itnet.model.categories import real_radius_m
    from itnet.model.scanner import BASE_HIDDEN, PAPER_VIEWS, SURFACE_VIEWS, sensor_views
    from itnet.model.train_run import train_config

    config = train_config(TrainOptions())
    assert (config.steps, config.decay_every, config.bn_decay_every) == (9000, 1125, 1125)
    assert config.symmetry is None and config.ema == 0.999 and config.compile is True
    assert config.bn_momentum == (0.5, 0.01)
    assert config.point_channels == (64, 128, 1024) and config.head_channels == (512, 256)
    assert config.scan_mix == [{}, PAPER_VIEWS] and config.val_scan == {}
    tuned = train_config(
        TrainOptions(symmetry="yaw180", ema=0.0, paper_views=False, surface_views=True,
                     base_hidden=True, sensors="kinect_v2", val_scanner="paper")
    )  # fmt: skip
    assert tuned.symmetry == "yaw180" and tuned.ema is None
    camera = sensor_views("kinect_v2", real_radius_m("chair"))
    views = [{}, SURFACE_VIEWS, camera, {**SURFACE_VIEWS, **camera}]  # each also by the camera
    assert tuned.scan_mix == [{**view, **BASE_HIDDEN} for view in views]
    assert tuned.val_scan == {**PAPER_VIEWS, **BASE_HIDDEN}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"loss": "cubic"}, "--loss must be one of"),
        ({"rotation": "euler"}, "--rotation must be one of"),
        ({"symmetry": "c3"}, "--symmetry must be auto or one of"),
        ({"point_channels": "64,x"}, "--point-channels takes positive integers"),
        ({"head_channels": "0"}, "--head-channels takes positive integers"),
        ({"val_scanner": "nearest"}, "unknown view rule"),
        ({"sensors": "kinect_v9"}, "unknown sensor"),
    ],
)
def test_train_config_refuses_a_bad_choice_by_its_option(change, message) -> None:  # type: ignore[no-untyped-def]
    from itnet.model.input_error import InputError
    from itnet.model.train_run import train_config

    with pytest.raises(InputError, match=message):
        train_config(TrainOptions(**change))
