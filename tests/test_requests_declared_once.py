"""Each request type declares its fields once; every way in is derived from it: the commands'
options (with the field's default and limits), the HTTP query and body, the clients' keyword
arguments and the page's defaults."""

from __future__ import annotations

import json
import re
from pathlib import Path
from urllib.parse import parse_qs

import httpx
import numpy as np
import pytest
import typer

from itnet.alignment.request import AlignRequest
from itnet.cli import app
from itnet.clients import ItnetClient, ItnetRequestError
from itnet.commands.request_options import REQUEST, cli_defaults, request_options
from itnet.pose.request import PoseRequest
from itnet.request_fields import RequestModel, parse_xyz
from itnet.scene.request import DEFAULT_BUDGET_MS, SceneRequest

STATIC = Path(__file__).resolve().parents[1] / "service" / "static"
# Every command that takes a request, by its path under `itnet`.
COMMANDS: dict[type[RequestModel], list[tuple[str, ...]]] = {
    PoseRequest: [("pose",), ("batch", "pose")],
    AlignRequest: [("align",), ("batch", "align")],
    SceneRequest: [("scene",), ("batch", "scene")],
}
# One value of each field other than its default, as a user would set it.
SET: dict[type[RequestModel], dict] = {
    PoseRequest: {"budget_ms": 20.0, "max_iterations": 7, "model": "chair", "ensemble": 4,
                  "mirror": False, "verify": True, "recheck": False, "centre": False,
                  "viewpoint": [0.0, 0.0, 0.0], "up": [0.0, -1.0, 0.0], "runs": True,
                  "units": "mm", "points_per_run": 128, "schedule": False, "strip": False},
    AlignRequest: {"model": "chair", "budget_ms": 80.0, "max_iterations": 5, "starts": 2,
                   "refine": False, "symmetry": "yaw180", "rivals": False, "candidates": 4,
                   "finalists": 2, "sweep": 8, "up_a": [0.0, -1.0, 0.0], "up_b": [0.0, 1.0, 0.0],
                   "viewpoint": [0.0, 0.0, 0.0], "units": "m"},
    SceneRequest: {"budget_ms": 400.0, "depth_scale": 5000.0, "up": [0.0, 0.0, 1.0],
                   "floor_centre": False, "along_floor": False, "recheck": False,
                   "scene_classifier": False, "split_touching": False, "unknown": False,
                   "named_split": False, "room": True},
}  # fmt: skip
KINDS = list(COMMANDS)


def _options(path: tuple[str, ...]) -> dict:
    """The options of ``itnet PATH...`` by name."""
    command = typer.main.get_command(app)
    for name in path:
        command = command.commands[name]  # type: ignore[attr-defined]
    return {p.name: p for p in command.params if p.param_type_name == "option"}


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.__name__)
def test_the_examples_set_every_field_to_other_than_its_default(kind):
    assert set(SET[kind]) == set(kind.model_fields)
    request = kind.model_validate(SET[kind])
    assert all(getattr(request, k) != f.default for k, f in kind.model_fields.items())


@pytest.mark.parametrize(
    ("kind", "path"), [(k, p) for k, paths in COMMANDS.items() for p in paths],
    ids=lambda v: v.__name__ if isinstance(v, type) else " ".join(v),
)  # fmt: skip
def test_every_command_offers_every_field_with_its_declared_default_and_limits(kind, path):
    options = _options(path)
    for name, spec in kind.model_fields.items():
        option = options.get(name)
        assert option is not None, f"itnet {' '.join(path)} has no option for {name}"
        assert f"--{name.replace('_', '-')}" in option.opts
        assert option.default == cli_defaults(kind).get(name, spec.default), name
        assert (spec.description or "")[:20].lower() in (option.help or "").lower(), name
        limits = {type(m).__name__: m for m in spec.metadata}
        if "Le" in limits:
            assert option.max == limits["Le"].le, name
        if "Ge" in limits:
            assert option.min == limits["Ge"].ge, name


def test_a_command_may_not_declare_a_request_field_itself():
    def pose(budget_ms: float = 5.0, request: PoseRequest = REQUEST) -> None: ...

    with pytest.raises(TypeError, match="budget_ms"):
        request_options(PoseRequest)(pose)


def test_the_derived_options_build_the_request_the_command_gets():
    got: list[SceneRequest] = []

    @request_options(SceneRequest)
    def scene(request: SceneRequest = REQUEST) -> None:
        got.append(request)

    runner_app = typer.Typer()
    runner_app.command()(scene)
    from typer.testing import CliRunner

    result = CliRunner().invoke(runner_app, ["--budget-ms", "400", "--up", "0,0,1",
                                             "--no-recheck", "--depth-scale", "5000"])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert got == [SceneRequest(budget_ms=400, up=[0, 0, 1], recheck=False, depth_scale=5000)]
    refused = CliRunner().invoke(runner_app, ["--up", "0,0,0"])
    assert refused.exit_code == 2 and "--up" in refused.output and got[1:] == []


def _operation(path: str) -> dict:
    from fastapi.testclient import TestClient

    from itnet.service.app import create_app

    schema = TestClient(create_app()).get("/openapi.json").json()
    return schema["paths"][path]["post"]


def test_the_http_api_takes_every_field():
    estimate = _operation("/v1/estimate")
    assert [p["name"] for p in estimate["parameters"]] == list(PoseRequest.model_fields)
    scene = _operation("/v1/scene")
    names = [p["name"] for p in scene["parameters"]]
    assert set(SceneRequest.model_fields) <= set(names)
    budget = next(p for p in scene["parameters"] if p["name"] == "budget_ms")
    assert budget["schema"]["default"] == DEFAULT_BUDGET_MS
    align = _operation("/v1/align")["requestBody"]["content"]["application/json"]["schema"]
    assert set(AlignRequest.model_fields) <= set(align["properties"])


def _sent(kind: type[RequestModel]) -> RequestModel:
    """What ItnetClient puts on the wire for ``kind`` with every field set by keyword."""
    seen: dict = {}

    def answer(request: httpx.Request) -> httpx.Response:
        seen["query"] = {k: v[0] for k, v in parse_qs(request.url.query.decode()).items()}
        seen["body"] = request.content
        return httpx.Response(500, json={"detail": "captured", "kind": "test"})

    client = ItnetClient("http://test")
    client._http = httpx.Client(base_url="http://test", transport=httpx.MockTransport(answer))
    cloud = np.zeros((40, 3))
    with pytest.raises(ItnetRequestError):  # the mock's 500: only the request matters here
        if kind is PoseRequest:
            client.estimate(cloud, **SET[kind])
        elif kind is AlignRequest:
            client.align(cloud, cloud, **SET[kind])
        else:
            client.scene(cloud, **SET[kind])
    if kind is SceneRequest:
        fields = {k: v for k, v in seen["query"].items() if k != "indices"}
        return SceneRequest.from_query(fields)
    body = json.loads(seen["body"])
    return kind.model_validate({k: v for k, v in body.items() if k in kind.model_fields})


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.__name__)
def test_the_client_sends_every_field_it_is_given_by_name(kind):
    assert _sent(kind) == kind.model_validate(SET[kind])


def test_the_client_refuses_a_field_the_request_does_not_have():
    with pytest.raises(TypeError, match="focal"):
        ItnetClient("http://test").scene(np.zeros((40, 3)), focal=500)


def test_the_pages_budgets_are_the_requests_defaults():
    text = (STATIC / "app.js").read_text()
    tabs = re.search(r"TAB_BUDGET_MS = \{([^}]*)\}", text)
    assert tabs is not None
    budgets = {k: float(v) for k, v in re.findall(r"(\w+): ([\d.]+)", tabs.group(1))}
    assert budgets == {"pose": PoseRequest().budget_ms, "align": AlignRequest().budget_ms,
                       "scene": SceneRequest().budget_ms}  # fmt: skip
    sent = re.findall(r"query\.set\('(\w+)'", (STATIC / "scene.js").read_text())
    assert set(sent) - {"fx", "fy", "cx", "cy"} <= set(SceneRequest.model_fields)


def test_one_parser_reads_three_numbers_everywhere():
    assert parse_xyz("0,-1,0") == parse_xyz((0, -1, 0)) == parse_xyz(np.array([0, -1, 0]))
    for bad in ("1,2", "a,b,c", "1,2,inf", "1,2,3,4", "", [1, 2]):
        with pytest.raises(ValueError, match="three numbers"):
            parse_xyz(bad)
    assert PoseRequest.from_query({"up": "0,-1,0"}).up == [0.0, -1.0, 0.0]
    assert SceneRequest.from_query({"up": "0,-1,0"}).to_query() == {"up": "0,-1,0"}


def test_the_models_listing_takes_the_cards_fields_as_the_card_declares_them():
    from itnet.model_card import ModelCard
    from itnet.service.schemas import CARD_KEPT_IN_FILE, ModelInfo, ServedModel

    card = set(ModelCard.model_fields) - CARD_KEPT_IN_FILE
    computed = set(ModelCard.model_computed_fields)
    assert set(ModelInfo.model_fields) == card | computed | set(ServedModel.model_fields)
    for name in card:
        served, declared = ModelInfo.model_fields[name], ModelCard.model_fields[name]
        assert served.annotation == declared.annotation, name
        assert served.default == declared.default, name
        assert served.description == declared.description, name


def test_the_scene_route_reads_its_query_into_a_scene_request():
    from itnet.service.api.routes.scene import _scene_request
    from itnet.service.errors import ServiceError

    query = {"fx": "525", "indices": "false", "budget_ms": "400", "up": "0,0,1", "recheck": "false"}
    assert _scene_request(query, 60_000) == SceneRequest(budget_ms=400, up=[0, 0, 1], recheck=False)
    for bad, said in (({"focal": "5"}, "focal"), ({"up": "0,0,0"}, "up"),
                      ({"budget_ms": "500"}, "over the limit of 450")):  # fmt: skip
        with pytest.raises(ServiceError) as refused:
            _scene_request(bad, 450)
        assert refused.value.status == 422 and said in str(refused.value.detail), bad
