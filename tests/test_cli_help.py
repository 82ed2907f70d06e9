"""`itnet --help`: the commands a user runs first, model-building ones in their own panel, and
every command still answering to its name."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from itnet.cli import BUILD, COMMANDS, USE, app

runner = CliRunner()
USER_COMMANDS = ["pose", "align", "classify", "serve", "models", "batch"]
BUILDING = ["average", "card", "centre-fit", "classify-train", "classify-export",
            "classify-experiment", "classify-size-prior", "verifier-train", "verifier-export"]  # fmt: skip


def test_help_lists_what_a_user_runs_before_the_model_building_commands() -> None:
    result = runner.invoke(app, ["--help"], terminal_width=100)
    assert result.exit_code == 0, result.output
    text = result.output
    building = text.index(BUILD)
    assert text.index(USE) < building
    for name in [*USER_COMMANDS, "train", "eval", "export", "bench"]:
        assert f" {name} " in text[:building], name
    for name in BUILDING:
        assert f" {name} " in text[building:], name


@pytest.mark.parametrize("name", [c[0] for c in COMMANDS] + ["batch"])
def test_every_command_answers_to_its_name_with_a_short_summary(name: str) -> None:
    result = runner.invoke(app, [name, "--help"], terminal_width=100)
    assert result.exit_code == 0, result.output
    summaries = {c[0]: c[3] for c in COMMANDS}
    if name in summaries:
        assert len(summaries[name]) <= 80 and summaries[name].endswith(".")
