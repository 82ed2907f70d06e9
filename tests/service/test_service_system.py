"""/v1/models, /healthz, /readyz, /metrics, /docs, settings and the default-model rule."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families

from itnet.pose.request import PoseRequest
from itnet.pose.runtime import LoadedModel
from itnet.service.app import create_app
from itnet.service.metrics import Metrics
from itnet.service.server import settings_to_env
from itnet.service.settings import LimitSettings, Settings
from itnet.service.state import ServiceState


def samples(client: TestClient) -> dict[tuple[str, frozenset], float]:
    text = client.get("/metrics").text
    return {
        (s.name, frozenset(s.labels.items())): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


def test_models_lists_the_card(client: TestClient) -> None:
    body = client.get("/v1/models").json()
    assert body["default_model"] == "tiny"
    (model,) = body["models"]
    assert (model["name"], model["category"], model["points"]) == ("tiny", "chair", 256)
    assert model["precision"] == "float32"
    assert model["trained_iterations"] == 5 and model["recommended_iterations"] == 5
    assert model["accuracy"] == {} and model["default"] is True
    assert model["step_ms"] > 0  # measured at warm-up
    assert "RMS" in model["normalization"]


def test_health_and_readiness(client: TestClient, tmp_path: Path) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = client.get("/readyz")
    assert ready.status_code == 200 and ready.json()["ready"] is True
    with TestClient(create_app(Settings(model_dir=tmp_path))) as empty:
        assert empty.get("/healthz").status_code == 200
        not_ready = empty.get("/readyz")
        assert not_ready.status_code == 503
        assert (
            not_ready.json()["ready"] is False and "no .onnx models" in not_ready.json()["detail"]
        )
        refused = empty.post("/v1/estimate", json={"points": [[0, 0, i] for i in range(40)]})
        assert refused.status_code == 503 and refused.json()["kind"] == "not_ready"


def test_a_default_model_that_is_not_loaded_is_not_ready(tiny_model_dir: Path) -> None:
    settings = Settings(model_dir=tiny_model_dir, default_model="chair", warm_up=False)
    with TestClient(create_app(settings)) as client:
        assert client.get("/readyz").status_code == 503
        assert "'chair' is not loaded" in client.get("/readyz").json()["detail"]


def test_metrics_count_requests_errors_and_iterations(client: TestClient) -> None:
    points = np.random.default_rng(3).normal(size=(100, 3)).tolist()
    before = samples(client)
    client.post("/v1/estimate", json={"points": points, "max_iterations": 3})
    client.post("/v1/estimate", json={"points": points[:5]})
    client.get("/no/such/path")
    after = samples(client)

    def grew(name: str, **labels: str) -> float:
        key = (name, frozenset(labels.items()))
        return after.get(key, 0.0) - before.get(key, 0.0)

    assert grew("itnet_requests_total", endpoint="/v1/estimate", status="200") == 1
    assert grew("itnet_requests_total", endpoint="/v1/estimate", status="422") == 1
    assert grew("itnet_requests_total", endpoint="unmatched", status="404") == 1
    assert grew("itnet_errors_total", kind="bad_cloud") == 1
    assert grew("itnet_iterations_count", model="tiny") == 1
    assert grew("itnet_iterations_sum", model="tiny") == 3
    assert grew("itnet_runs_total", model="tiny", stopped_by="max_iterations") == 1
    assert grew("itnet_request_duration_seconds_count", endpoint="/v1/estimate") == 2
    assert client.get("/metrics").headers["content-type"].startswith("text/plain")


def test_openapi_documents_both_bodies_with_examples(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    post = spec["paths"]["/v1/estimate"]["post"]
    content = post["requestBody"]["content"]
    assert set(content) == {"application/json", "application/octet-stream"}
    assert len(content["application/json"]["example"]["points"]) >= 32
    # a binary body's query takes every field of the JSON body but the points
    assert [p["name"] for p in post["parameters"]] == list(PoseRequest.model_fields)
    assert {"ensemble", "verify", "mirror", "centre", "units"} <= set(PoseRequest.model_fields)
    query = {p["name"]: p for p in post["parameters"]}
    assert query["up"]["schema"]["type"] == "string"  # 'x,y,z'
    assert query["ensemble"]["schema"]["maximum"] == 16
    assert {"200", "400", "404", "413", "415", "422", "503"} <= set(post["responses"])
    assert "/v1/models" in spec["paths"] and "/readyz" in spec["paths"]
    assert client.get("/docs").status_code == 200


def test_settings_from_the_environment_round_trip(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("ITNET_MODEL_DIR", str(tmp_path))
    monkeypatch.setenv("ITNET_DEFAULT_MODEL", "sofa")
    monkeypatch.setenv("ITNET_LIMITS__MAX_POINTS", "1234")
    monkeypatch.setenv("ITNET_LIMITS__MAX_CONCURRENT_REQUESTS", "3")
    settings = Settings()
    assert (settings.model_dir, settings.default_model) == (tmp_path, "sofa")
    assert (settings.limits.max_points, settings.limits.max_concurrent_requests) == (1234, 3)
    assert settings.limits.engine_limits().max_points == 1234
    for name in ("ITNET_MODEL_DIR", "ITNET_DEFAULT_MODEL"):
        monkeypatch.delenv(name)
    changed = Settings(model_dir=tmp_path, threads=1, warm_up=False,
                       limits=LimitSettings(max_budget_ms=77.5, min_points=40))  # fmt: skip
    for name, value in settings_to_env(changed).items():
        monkeypatch.setenv(name, value)
    assert Settings() == changed


def test_limits_must_be_consistent() -> None:
    with pytest.raises(ValueError, match="min_points"):
        LimitSettings(min_points=100, max_points=50)


@pytest.mark.parametrize(
    ("loaded", "configured", "expected"),
    [
        (["chair", "table"], None, "chair"),
        (["table"], None, "table"),
        (["sofa", "table"], None, None),
        (["chair", "table"], "table", "table"),
    ],
)
def test_default_model_rule(
    tiny_model_dir: Path,
    loaded: list[str],
    configured: str | None,
    expected: str | None,
    tiny_models: Callable[[list[str]], dict[str, LoadedModel]],
) -> None:
    settings = Settings(model_dir=tiny_model_dir, default_model=configured)
    state = ServiceState(settings, Metrics(), models=tiny_models(loaded))
    state.load()
    assert state.default_model_name() == expected
    if expected is None:
        with pytest.raises(Exception, match="name a model"):
            state.model(None)
    else:
        assert state.model(None) is state.models[expected]


@pytest.fixture(scope="module")
def tiny_models(settings: Settings) -> Callable[[list[str]], dict[str, LoadedModel]]:
    from itnet.pose.runtime import load_models

    (model,) = load_models(settings.model_dir, warm_up=False).values()
    return lambda names: dict.fromkeys(names, model)


def test_the_serving_side_never_imports_torch() -> None:
    code = (
        "import sys, itnet.service.app, itnet.service.server, itnet.cli\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr


def test_the_docs_list_every_setting() -> None:
    docs = (Path(__file__).resolve().parents[2] / "docs" / "service.md").read_text()
    for name in settings_to_env(Settings(default_model="x")):
        assert f"`{name}`" in docs, f"{name} is not documented in docs/service.md"
