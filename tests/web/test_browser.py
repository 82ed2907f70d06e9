"""The page in a real browser (headless Chromium) against a live ``itnet serve``: what a person
sees. The page and the API must agree, so every run stops by ``max_iterations`` under a
generous budget: both answers come from the same iterations on the same cloud."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from itnet.cloud_io import read_cloud
from itnet.geometry import rotation_error_deg

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.browser]
EXAMPLES = Path(__file__).resolve().parents[2] / "itnet" / "examples"
DONE = "['done', 'failed'].includes(document.body.dataset.run)"


def result(page: Any) -> dict:
    page.wait_for_function(DONE, timeout=30_000)
    assert page.evaluate("document.body.dataset.run") == "done", page.text_content("#status")
    return json.loads(page.text_content("#result"))


def estimate(server: Any, points: np.ndarray, **params: Any) -> dict:
    body = {"points": points.tolist(), **params}
    reply = httpx.post(f"{server.url}/v1/estimate", json=body, timeout=30)
    assert reply.status_code == 200, reply.text
    return reply.json()


def test_a_link_runs_an_example_live_and_ends_with_the_apis_pose(live_server, browser_page):
    page, errors = browser_page, []
    page.on("pageerror", lambda err: errors.append(str(err)))
    page.goto(f"{live_server.url}/?example=chair_a&model=chair&budget_ms=5000"
              "&max_iterations=8&play_ms=120&run=1")  # fmt: skip
    # The iteration counter, read as a person would: it climbs over time, one step at a time.
    seen, start = [], time.monotonic()
    while page.evaluate("document.body.dataset.run") != "done" and time.monotonic() - start < 20:
        seen.append(int(page.text_content("#iteration")))
        page.wait_for_timeout(40)
    shown = result(page)
    page.wait_for_function("document.getElementById('iteration').textContent === '8'")
    assert seen == sorted(seen) and len(set(seen)) >= 4, seen  # rising, seen at several values
    assert seen[0] <= 2

    api = estimate(live_server, read_cloud(EXAMPLES / "chair_a.ply"), model="chair",
                   budget_ms=5000, max_iterations=8)  # fmt: skip
    assert shown["stopped_by"] == api["stopped_by"] == "max_iterations"
    assert shown["iterations"] == api["iterations"] == 8
    for key in ("T_canonical_from_input", "quat_wxyz", "quat_xyzw", "translation"):
        assert np.allclose(shown[key], api[key], atol=1e-6), key
    assert page.text_content("#stopped-by") == "max_iterations"
    # The pose panel shows the same matrix, and the URL still holds the run.
    first_row = page.text_content("#pose pre").split("\n")[0].split()
    assert np.allclose([float(v) for v in first_row], api["T_canonical_from_input"][0], atol=1e-6)
    assert "example=chair_a" in page.url and "run=1" in page.url
    assert page.evaluate("document.getElementById('notice').hidden")  # WebGL drew the view
    assert not errors


def test_the_ensemble_control_fuses_runs_as_the_api_does(live_server, browser_page):
    page = browser_page
    page.goto(f"{live_server.url}/?example=chair_a&model=chair&budget_ms=5000"
              "&max_iterations=3&ensemble=4&play_ms=0&run=1")  # fmt: skip
    shown = result(page)
    assert page.input_value("#ensemble") == "4" and "ensemble=4" in page.url
    api = estimate(live_server, read_cloud(EXAMPLES / "chair_a.ply"), model="chair",
                   budget_ms=5000, max_iterations=3, ensemble=4)  # fmt: skip
    assert shown["ensemble"] == api["ensemble"] == 4 and shown["iterations"] == 3
    assert np.allclose(shown["T_canonical_from_input"], api["T_canonical_from_input"], atol=1e-6)
    assert "4 runs fused" in page.text_content("#status")
    assert api["centre"] is True and "centre corrected" in page.text_content("#status")
    assert api["verified"] is True and shown["verified"] is True  # the chair's card: verify_fused
    assert "fused around the run verify found likeliest" in page.text_content("#status")
    # Back to the model's count (8 runs for the chair): the request carries no
    # ensemble, the URL forgets it, and the reply says how many the card's default ran.
    page.select_option("#ensemble", "")
    page.click("#run")
    default = result(page)
    assert default["ensemble"] == 8 and "ensemble=" not in page.url
    assert "8 runs fused" in page.text_content("#status")


def test_the_unit_control_lets_auto_count_the_size(live_server, browser_page):
    page = browser_page
    page.goto(f"{live_server.url}/?example=chair_a&model=auto&units=m&budget_ms=5000"
              "&max_iterations=3&play_ms=0&run=1")  # fmt: skip
    shown = result(page)
    assert page.input_value("#units") == "m" and "units=m" in page.url
    api = estimate(live_server, read_cloud(EXAMPLES / "chair_a.ply"), model="auto",
                   units="m", budget_ms=5000, max_iterations=3)  # fmt: skip
    assert shown["category"] == api["category"] == "chair" and shown["size_used"] is True
    assert shown["size_m"] == pytest.approx(api["size_m"])
    # Unknown again: the request carries no unit, the reply no size, the URL forgets it.
    page.select_option("#units", "")
    page.click("#run")
    plain = result(page)
    assert "size_m" not in plain and plain["size_used"] is False and "units=" not in page.url


def test_the_up_control_holds_the_pose_upright_as_the_api_does(live_server, browser_page):
    page = browser_page
    page.goto(f"{live_server.url}/?example=chair_a&model=chair&up=0.1,-1,0.2&budget_ms=5000"
              "&max_iterations=3&play_ms=0&run=1")  # fmt: skip
    shown = result(page)
    assert page.input_value("#up") == "0.1,-1,0.2" and "up=0.1" in page.url
    api = estimate(live_server, read_cloud(EXAMPLES / "chair_a.ply"), model="chair",
                   up=[0.1, -1, 0.2], budget_ms=5000, max_iterations=3)  # fmt: skip
    assert np.allclose(shown["up"], api["up"]) and shown["iterations"] == 3
    assert np.allclose(shown["T_canonical_from_input"], api["T_canonical_from_input"], atol=1e-6)
    # Cleared: the request carries no up, the reply none, the URL forgets it.
    page.fill("#up", "")
    page.dispatch_event("#up", "change")
    page.click("#run")
    free = result(page)
    assert "up" not in free and "up=" not in page.url


def test_a_dropped_file_is_read_by_the_server_and_a_bad_one_is_refused(
    live_server, browser_page, tmp_path
):
    points = read_cloud(EXAMPLES / "chair_b.ply")
    xyz = tmp_path / "scan.xyz"
    np.savetxt(xyz, points)
    page = browser_page
    page.goto(f"{live_server.url}/?max_iterations=5&budget_ms=5000&play_ms=0")
    page.wait_for_function("document.body.dataset.ready === 'true'")
    page.set_input_files("#file", str(xyz))
    page.wait_for_function("document.getElementById('status').textContent.startsWith('scan.xyz')")
    assert f"{len(points)} points" in page.text_content("#status")
    page.click("#run")
    shown = result(page)
    api = estimate(live_server, points, budget_ms=5000, max_iterations=5)
    assert np.allclose(shown["T_canonical_from_input"], api["T_canonical_from_input"], atol=1e-5)

    bad = tmp_path / "broken.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\n")  # no end_header
    page.set_input_files("#file", str(bad))
    page.wait_for_function("document.getElementById('status').classList.contains('error')")
    assert "broken.ply" in page.text_content("#status")


def test_the_alignment_tab_moves_a_onto_b(live_server, browser_page):
    pytest.importorskip("open3d")
    page = browser_page
    # a generous budget: the runs end by their iteration count, on the page as in the API,
    # even on a loaded machine (with the default 50 ms, a slow moment cut one run short)
    page.goto(f"{live_server.url}/?tab=align&a=chair_a&b=chair_b&model=chair&budget_ms=5000&run=1")
    shown = result(page)
    truth = json.loads((EXAMPLES / "chair_truth.json").read_text())["T_b_from_a"]
    t = np.array(shown["T_b_from_a"])
    assert shown["refined"] is True
    assert rotation_error_deg(t[:3, :3], np.array(truth)[:3, :3]) < 5.0
    assert "error against the example's truth" in page.text_content("#align-summary")
    body = {"points_a": read_cloud(EXAMPLES / "chair_a.ply").tolist(),
            "points_b": read_cloud(EXAMPLES / "chair_b.ply").tolist(), "model": "chair",
            "budget_ms": 5000}  # fmt: skip
    api = httpx.post(f"{live_server.url}/v1/align", json=body, timeout=60).json()
    # The same alignment. Not to the last digit: the int8 graph quantises each call's
    # activations over the whole batch, so a step batched with another request's in flight
    # (which ones meet is a loaded machine's timing) moves a pose by a fraction of a degree.
    other = np.array(api["T_b_from_a"])
    assert rotation_error_deg(t[:3, :3], other[:3, :3]) < 0.5
    assert np.linalg.norm(t[:3, 3] - other[:3, 3]) < 0.01


def test_the_alignment_tab_follows_its_example_pairs_category(live_server, browser_page):
    """Opened without a model, the align tab shows the default model's pair (the chair's); a bed
    pair, opened or picked, selects the bed's model; a chosen 'auto' stays."""
    page = browser_page
    page.goto(f"{live_server.url}/?tab=align")
    page.wait_for_function("document.body.dataset.ready === 'true'")
    assert page.input_value("#example-a") == "chair_a" and page.input_value("#model") == "chair"
    page.select_option("#example-a", "bed_a")
    page.select_option("#example-b", "bed_b")
    assert page.input_value("#model") == "bed"
    page.goto(f"{live_server.url}/?tab=align&a=toilet_a&b=toilet_b")
    page.wait_for_function("document.body.dataset.ready === 'true'")
    assert page.input_value("#model") == "toilet"
    page.select_option("#model", "auto")
    page.select_option("#example-a", "table_a")
    page.select_option("#example-b", "table_b")
    assert page.input_value("#model") == "auto"


def test_a_model_that_needs_up_aligns_an_example_pair_by_its_scans_ups(live_server, browser_page):
    """The night stand requires up: the page sends the example pair's ups (each scan's, as a
    level-sensing camera gives them), says so, and agrees with the API given the same."""
    pytest.importorskip("open3d")
    page = browser_page
    page.goto(f"{live_server.url}/?tab=align&a=night_stand_a&b=night_stand_b&model=night_stand"
              "&budget_ms=5000&run=1")  # fmt: skip
    shown = result(page)
    known = json.loads((EXAMPLES / "night_stand_truth.json").read_text())
    assert np.allclose(shown["up_a"], known["up_a"]) and np.allclose(shown["up_b"], known["up_b"])
    assert "held upright by each scan's up" in page.text_content("#align-summary")
    t = np.array(shown["T_b_from_a"])
    assert rotation_error_deg(t[:3, :3], np.array(known["T_b_from_a"])[:3, :3]) < 5.0
    body = {"points_a": read_cloud(EXAMPLES / "night_stand_a.ply").tolist(),
            "points_b": read_cloud(EXAMPLES / "night_stand_b.ply").tolist(),
            "model": "night_stand", "budget_ms": 5000, "up_a": known["up_a"],
            "up_b": known["up_b"]}  # fmt: skip
    api = httpx.post(f"{live_server.url}/v1/align", json=body, timeout=60).json()
    # The same alignment. Not to the last digit: the int8 graph quantises each call's
    # activations over the whole batch, so a step batched with another request's in flight
    # (which ones meet is a loaded machine's timing) moves a pose by a fraction of a degree.
    other = np.array(api["T_b_from_a"])
    assert rotation_error_deg(t[:3, :3], other[:3, :3]) < 0.5
    assert np.linalg.norm(t[:3, 3] - other[:3, 3]) < 0.01


def test_auto_is_offered_when_the_server_has_a_classifier(live_server, browser_page):
    auto = httpx.get(f"{live_server.url}/v1/models").json().get("auto")
    if auto is None:
        pytest.skip("no classifier shipped: the page offers no 'auto'")
    page = browser_page
    page.goto(f"{live_server.url}/?example=chair_a&model=auto&budget_ms=5000&max_iterations=5"
              "&play_ms=0&run=1")  # fmt: skip
    shown = result(page)
    assert "auto" in page.eval_on_selector_all("#model option", "os => os.map(o => o.value)")
    assert page.text_content("#status").startswith("done")
    api = estimate(live_server, read_cloud(EXAMPLES / "chair_a.ply"), model="auto",
                   budget_ms=5000, max_iterations=5)  # fmt: skip
    assert shown["model"] == api["model"]
    assert np.allclose(shown["T_canonical_from_input"], api["T_canonical_from_input"], atol=1e-6)


def test_auto_with_up_runs_the_upright_classifier_as_the_api_does(live_server, browser_page):
    """The shipped upright classifier joins 'auto' when the Up field is set: the reply says so,
    and the page agrees with the API given the same up (the chair's true up in its scan)."""
    auto = httpx.get(f"{live_server.url}/v1/models").json().get("auto")
    if auto is None or auto.get("upright") is None:
        pytest.skip("no upright classifier shipped")
    up = json.loads((EXAMPLES / "chair_truth.json").read_text())["T_canonical_from_a"][1][:3]
    text = ",".join(f"{v:.6f}" for v in up)
    page = browser_page
    page.goto(f"{live_server.url}/?example=chair_a&model=auto&up={text}&budget_ms=5000"
              "&max_iterations=5&play_ms=0&run=1")  # fmt: skip
    shown = result(page)
    assert shown["classified_upright"] is True and shown["category"] == "chair"
    api = estimate(live_server, read_cloud(EXAMPLES / "chair_a.ply"), model="auto",
                   up=[float(v) for v in text.split(",")], budget_ms=5000, max_iterations=5)  # fmt: skip
    assert api["classified_upright"] is True
    assert np.isclose(shown["category_probability"], api["category_probability"], atol=1e-6)
    assert np.allclose(shown["T_canonical_from_input"], api["T_canonical_from_input"], atol=1e-6)
