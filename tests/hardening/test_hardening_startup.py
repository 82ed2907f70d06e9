"""A model that is missing or corrupt at start-up: ``itnet serve`` says which and why and exits 2
before binding a port; an app started anyway stays alive and says on /readyz it is not ready."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
import typer
from fastapi.testclient import TestClient
from hardening_helpers import with_card
from typer.testing import CliRunner

from itnet.commands.serve import serve
from itnet.service.app import create_app
from itnet.service.settings import Settings


def missing_folder(folder: Path, tiny: Path) -> str:
    shutil.rmtree(folder)
    return "no .onnx models found"


def empty_folder(folder: Path, tiny: Path) -> str:
    return "no .onnx models found"


def random_bytes(folder: Path, tiny: Path) -> str:
    (folder / "chair.onnx").write_bytes(bytes(range(256)) * 40)
    return "cannot load the ONNX graph"


def truncated(folder: Path, tiny: Path) -> str:
    data = tiny.read_bytes()
    (folder / "chair.onnx").write_bytes(data[: len(data) // 2])
    return "cannot load the ONNX graph"


def empty_file(folder: Path, tiny: Path) -> str:
    (folder / "chair.onnx").write_bytes(b"")
    return "cannot load the ONNX graph"


def no_card(folder: Path, tiny: Path) -> str:
    with_card(tiny, folder / "chair.onnx", None)
    return "not an itnet model"


def corrupt_card(folder: Path, tiny: Path) -> str:
    """Regression: a card that fails validation escaped as a pydantic error and crashed the
    app's start-up instead of leaving it alive and not ready."""
    with_card(tiny, folder / "chair.onnx", '{"name": 5, "category": "chair"')
    return "unreadable model card"


def one_bad_among_good(folder: Path, tiny: Path) -> str:
    shutil.copy(tiny, folder / "tiny.onnx")
    (folder / "zzz.onnx").write_bytes(b"\x08\x07" + b"\xff" * 100)
    return "zzz.onnx: cannot load the ONNX graph"


CASES = [missing_folder, empty_folder, random_bytes, truncated, empty_file, no_card,
         corrupt_card, one_bad_among_good]  # fmt: skip


@pytest.fixture(params=CASES, ids=[case.__name__ for case in CASES])
def broken(
    request: pytest.FixtureRequest, tmp_path: Path, tiny_model_dir: Path
) -> tuple[Path, str]:
    """A model folder broken in one way, and words the error must contain."""
    folder = tmp_path / "models"
    folder.mkdir()
    make: Callable[[Path, Path], str] = request.param
    return folder, make(folder, tiny_model_dir / "tiny.onnx")


def test_serve_exits_2_with_the_reason(broken: tuple[Path, str]) -> None:
    folder, words = broken
    app = typer.Typer()
    app.command()(serve)
    result = CliRunner().invoke(app, ["--model-dir", str(folder), "--port", "1"])
    assert result.exit_code == 2, result.output
    assert "error: cannot load the models" in result.output and words in result.output
    assert "Traceback" not in result.output


def test_the_app_stays_alive_and_not_ready(broken: tuple[Path, str]) -> None:
    folder, words = broken
    with TestClient(create_app(Settings(model_dir=folder, warm_up=False))) as client:
        assert client.get("/healthz").json() == {"status": "ok"}
        ready = client.get("/readyz")
        assert ready.status_code == 503 and ready.json()["ready"] is False
        assert words in ready.json()["detail"]
        refused = client.post("/v1/estimate", json={"points": [[0, 0, i] for i in range(40)]})
        assert refused.status_code == 503 and refused.json()["kind"] == "not_ready"
