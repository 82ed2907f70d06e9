"""``itnet bench`` measures every model of a folder and prints its table."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from itnet.cli import app


@pytest.mark.timing  # replies counted in a 0.3 s window, four clients at once
def test_bench_prints_a_row_per_model_and_shape_and_the_loop_overhead(tiny_model_dir) -> None:
    result = CliRunner().invoke(
        app, ["bench", "--model-dir", str(tiny_model_dir), "--repeats", "3", "--clients", "1,4",
              "--duration-s", "0.3", "--budget-ms", "50"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "machine:" in result.output and "CPUs" in result.output
    rows = [line for line in result.output.splitlines() if line.startswith("| tiny |")]
    # The tiny model's own 256 points first, then the paper's shapes.
    assert [r.split("|")[3].strip() for r in rows] == ["1×256", "1×1024", "1×4096", "8×1024"]
    assert all(r.split("|")[2].strip() == "float32" for r in rows)
    assert "tiny: anytime loop" in result.output and "overhead" in result.output
    # The load table: batching on and off, a row for each count of requests at once.
    load = [line.split("|") for line in result.output.splitlines() if line.startswith("| o")]
    assert [(r[1].strip(), r[2].strip()) for r in load] == [
        ("on", "1"),
        ("on", "4"),
        ("off", "1"),
        ("off", "4"),
    ]
    assert all(float(r[3]) > 0 and float(r[6]) >= 1 for r in load)  # replies, steps a reply
    assert load[0][5].strip() == "100%"
    assert all(float(r[9]) == 1.0 for r in load if r[1].strip() == "off")  # a call a step
    assert float(load[1][9]) > 1.0  # four float32 requests at once share calls


@pytest.mark.timing  # replies counted in a 0.2 s window
def test_bench_measures_a_model_that_requires_up(tmp_path, export_model) -> None:  # type: ignore[no-untyped-def]
    """A card that requires up (the night stand's, the dresser's) gets its loop measured held
    upright, one run: it used to stop the whole command with the engine's refusal."""
    from itnet.model_card import ModelCard

    card = ModelCard(name="box", category="dresser", points=256, recommended_iterations=3,
                     requires_up=True, recommended_ensemble=8)  # fmt: skip
    export_model(card, tmp_path / "box.onnx")
    result = CliRunner().invoke(app, ["bench", "--model-dir", str(tmp_path), "--repeats", "2",
                                      "--clients", "1", "--duration-s", "0.2"])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "box: anytime loop" in result.output
    load = [line.split("|") for line in result.output.splitlines() if line.startswith("| on |")]
    assert float(load[0][3]) > 0 and load[0][7].strip() == "0"  # posed upright, none refused


def test_bench_refuses_an_unknown_model(tiny_model_dir) -> None:
    result = CliRunner().invoke(
        app, ["bench", "--model-dir", str(tiny_model_dir), "--model", "sofa"]
    )
    assert result.exit_code == 2 and "unknown model 'sofa'" in result.output
