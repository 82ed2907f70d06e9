"""PoseRequest is the one declaration of a request's options: every way in offers all of them."""

from __future__ import annotations

import inspect
import json
import re
from pathlib import Path
from urllib.parse import parse_qs

import httpx
import numpy as np
import pytest

from itnet.clients import AsyncItnetClient, ItnetClient, ItnetRequestError
from itnet.commands.pose import pose as pose_command
from itnet.pose.request import REQUEST_FIELDS, PoseRequest

STATIC = Path(__file__).resolve().parents[2] / "service" / "static"
# One value of each field other than its default, as a user would set it.
SET = {"budget_ms": 20.0, "max_iterations": 7, "model": "chair", "ensemble": 4, "mirror": False,
       "verify": True, "recheck": False, "centre": False, "viewpoint": [0.0, 0.0, 0.0],
       "up": [0.0, -1.0, 0.0], "runs": True, "units": "mm", "points_per_run": 128,
       "schedule": False, "strip": False}  # fmt: skip
# The page draws the served pose; each run's own pose is for alignment's hypotheses.
PAGE_LEAVES_OUT = {"runs"}


def test_the_examples_cover_every_field():
    assert set(SET) == set(REQUEST_FIELDS)
    request = PoseRequest.model_validate(SET)
    assert all(getattr(request, k) != f.default for k, f in PoseRequest.model_fields.items())


def test_itnet_pose_has_an_option_for_every_field():
    options = set(inspect.signature(pose_command).parameters)
    assert set(REQUEST_FIELDS) <= options, set(REQUEST_FIELDS) - options


def _captured(binary: bool) -> dict:
    """What ItnetClient.estimate puts on the wire with every field set."""
    seen: dict = {}

    def answer(request: httpx.Request) -> httpx.Response:
        if binary:
            seen.update({k: v[0] for k, v in parse_qs(request.url.query.decode()).items()})
        else:
            seen.update(json.loads(request.content))
        return httpx.Response(500, json={"detail": "captured", "kind": "test"})

    client = ItnetClient("http://test")
    client._http = httpx.Client(base_url="http://test", transport=httpx.MockTransport(answer))
    with pytest.raises(ItnetRequestError):  # the mock's 500: only the request matters here
        client.estimate(np.zeros((40, 3)), binary=binary, **SET)
    return seen


def test_the_python_clients_send_every_field_in_both_bodies():
    as_json = _captured(binary=False)
    assert {k: v for k, v in as_json.items() if k != "points"} == SET
    as_query = _captured(binary=True)
    assert PoseRequest.from_query(as_query) == PoseRequest.model_validate(SET)
    # the async client and the streams take the same PoseRequest
    for method in (AsyncItnetClient.estimate, AsyncItnetClient.stream, ItnetClient.stream):
        assert "request" in inspect.signature(method).parameters


def test_the_page_has_a_control_for_every_field():
    html = (STATIC / "index.html").read_text()
    fields = set(re.findall(r'data-field="([a-z_]+)"', html))
    assert fields == set(REQUEST_FIELDS) - PAGE_LEAVES_OUT, fields ^ set(REQUEST_FIELDS)
    assert "collectRequest" in (STATIC / "app.js").read_text()
