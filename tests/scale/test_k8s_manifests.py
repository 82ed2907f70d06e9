"""The Kubernetes manifests in deploy/k8s: valid against the Kubernetes schemas (offline, with
kubernetes-validate), and consistent with the app, the Dockerfile and the server's drain."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
K8S = ROOT / "deploy" / "k8s"
KUBERNETES_VERSION = "1.30.0"  # the oldest still supported upstream when this was written


def documents() -> dict[str, dict]:
    kustomization = yaml.safe_load((K8S / "kustomization.yaml").read_text())
    docs = [
        d for f in kustomization["resources"] for d in yaml.safe_load_all((K8S / f).read_text())
    ]
    return {d["kind"]: d for d in docs}


def container() -> dict:
    return documents()["Deployment"]["spec"]["template"]["spec"]["containers"][0]


def quantity(value: str) -> float:
    """A Kubernetes quantity ('500m', '1', '256Mi', '1Gi') -> a plain number."""
    units = {"m": 1e-3, "Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "": 1}
    number, unit = re.fullmatch(r"([0-9.]+)([A-Za-z]*)", str(value)).groups()  # type: ignore[union-attr]
    return float(number) * units[unit]


@pytest.mark.parametrize("kind", ["Deployment", "Service", "HorizontalPodAutoscaler"])
def test_manifests_are_valid_kubernetes(kind: str) -> None:
    kubernetes_validate = pytest.importorskip("kubernetes_validate")
    kubernetes_validate.validate(documents()[kind], KUBERNETES_VERSION, strict=True)


def test_schema_validation_catches_a_mistake() -> None:
    """The validator is not a rubber stamp: a probe with a misspelt field fails."""
    kubernetes_validate = pytest.importorskip("kubernetes_validate")
    deployment = documents()["Deployment"]
    deployment["spec"]["template"]["spec"]["containers"][0]["livenessProbe"]["httpGett"] = {}
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(deployment, KUBERNETES_VERSION, strict=True)


def test_probes_hit_the_apps_routes_on_the_served_port() -> None:
    from fastapi.testclient import TestClient

    from itnet.service.app import create_app

    c = container()
    with TestClient(create_app()) as app:  # the shipped models, as in the image
        for probe in ("livenessProbe", "readinessProbe", "startupProbe"):
            assert app.get(c[probe]["httpGet"]["path"]).status_code == 200, probe
    assert c["livenessProbe"]["httpGet"]["path"] == "/healthz"
    assert c["readinessProbe"]["httpGet"]["path"] == "/readyz"
    ports = {p["name"]: p["containerPort"] for p in c["ports"]}
    exposed = re.search(r"^EXPOSE (\d+)", (ROOT / "Dockerfile").read_text(), re.M)
    assert exposed and ports["http"] == int(exposed.group(1))
    args = c["args"]
    assert args[:2] == ["itnet", "serve"] and int(args[args.index("--port") + 1]) == ports["http"]
    for probe in ("livenessProbe", "readinessProbe", "startupProbe"):
        assert c[probe]["httpGet"]["port"] in ("http", ports["http"])
    service = documents()["Service"]
    assert service["spec"]["ports"][0]["targetPort"] in ("http", ports["http"])
    labels = documents()["Deployment"]["spec"]["template"]["metadata"]["labels"]
    assert service["spec"]["selector"].items() <= labels.items()


def test_the_grace_period_covers_the_pre_stop_and_the_drain(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """SIGTERM comes after preStop; the server then drains for up to graceful_shutdown_s (as the
    environment sets it, read by the service's own Settings); the kubelet kills at the grace."""
    from itnet.service.settings import Settings

    c = container()
    for var in c["env"]:
        monkeypatch.setenv(var["name"], var["value"])
    settings = Settings()  # every ITNET_* variable of the manifest is a valid setting
    pre_stop = c["lifecycle"]["preStop"]["exec"]["command"]
    assert pre_stop[0] == "sleep"
    grace = documents()["Deployment"]["spec"]["template"]["spec"]["terminationGracePeriodSeconds"]
    assert grace > float(pre_stop[1]) + settings.server.graceful_shutdown_s
    # The pod's CPUs are stated, not taken from the node: steps fit the CPU limit.
    cpus = quantity(c["resources"]["limits"]["cpu"])
    assert settings.threads * (settings.concurrent_steps or 0) <= cpus


def test_requests_fit_the_limits_and_the_measured_memory() -> None:
    resources = container()["resources"]
    for what in ("cpu", "memory"):
        assert quantity(resources["requests"][what]) <= quantity(resources["limits"][what])
    # Measured (docs/scale.md): the server with the shipped models peaks at 594 MiB, and the
    # JSON parse worker adds up to ~250 MiB under the largest bodies.
    assert quantity(resources["requests"]["memory"]) >= 600 * 2**20
    assert quantity(resources["limits"]["memory"]) >= (600 + 250) * 2**20
    securityContext = documents()["Deployment"]["spec"]["template"]["spec"]["securityContext"]
    user = re.search(r"^USER (\d+)", (ROOT / "Dockerfile").read_text(), re.M)
    assert user and securityContext["runAsUser"] == int(user.group(1))


def test_the_autoscaler_scales_the_deployment_on_cpu() -> None:
    hpa, deployment = documents()["HorizontalPodAutoscaler"], documents()["Deployment"]
    assert hpa["apiVersion"] == "autoscaling/v2"
    target = hpa["spec"]["scaleTargetRef"]
    assert (target["kind"], target["name"]) == ("Deployment", deployment["metadata"]["name"])
    assert [m["resource"]["name"] for m in hpa["spec"]["metrics"]] == ["cpu"]
    assert 1 <= hpa["spec"]["minReplicas"] <= hpa["spec"]["maxReplicas"]
    assert "cpu" in container()["resources"]["requests"]  # utilisation is relative to it
