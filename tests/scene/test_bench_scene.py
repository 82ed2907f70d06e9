"""The scenes benchmark end to end on a tiny tree of box shapes: the scene kinds it is asked for,
its report and its rows."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks import bench_scene
from itnet.model.scenes import SIZES, mixed_at_edges


def _box(rng: np.random.Generator, n: int = 1024) -> np.ndarray:
    """A noisy box, z up (ModelNet's frame), whose upper half stands at its +y end only (a
    chair's back), so that every category's orientation check keeps it."""
    size = np.array([0.6, 0.5, 0.8]) * rng.uniform(0.9, 1.1, size=3)
    face = rng.integers(6, size=4 * n)
    points = rng.uniform(-1, 1, size=(4 * n, 3))
    points[np.arange(4 * n), face // 2] = np.where(face % 2, 1.0, -1.0)
    points = points[(points[:, 2] < 0) | (points[:, 1] > 0.4)][:n]
    return points * size + rng.normal(0, 0.005, size=points.shape)


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from modelnet_tree import write_modelnet_tree

    root = tmp_path_factory.mktemp("bench_scene")
    return write_modelnet_tree(root / "data", {name: _box for name in SIZES},
                               np.random.default_rng(0), train=2, test=4)  # fmt: skip


def test_a_level_camera_s_scenes_of_the_categories_drawn(data: Path, tmp_path: Path) -> None:
    out = tmp_path / "report.json"
    bench_scene.main(["--split", "validation", "--scenes", "3", "--no-large", "--data", str(data),
                      "--cache", str(tmp_path / "cache"), "--draw", "chair,toilet", "--pitch",
                      "0,0", "--most", "2", "--cut-off", "--out", str(out)])  # fmt: skip
    report = json.loads(out.read_text())
    assert report["drawn"] == ["chair", "toilet"] and report["pitch_deg"] == [0.0, 0.0]
    assert report["most"] == 2 and report["cut_off"] is True
    objects = [row for row in report["rows"] if row["kind"] == "object"]
    assert 3 <= len(objects) <= 6
    assert {row["category"] for row in objects} <= {"chair", "toilet"}
    assert {(row["scene"], row["object"]) for row in objects} <= {
        (s, k) for s in range(3) for k in (1, 2)
    }  # what pairs two runs' objects (benchmarks.compare_scenes)
    size = report["320x240"]
    assert size["found"]["of"] == sum(row["visible"] for row in objects)
    assert 0 <= size["right"]["count"] <= size["found"]["count"] <= size["found"]["of"]
    assert size["ms_median"] > 0 and report["flying_pixels"] == 0.0


def test_flying_pixels_lie_between_an_edge_s_two_surfaces() -> None:
    """A chair 2 m away before a wall 3 m away: with every edge pixel mixed, the pixels of the
    chair's rim take depths between 2 and 3 m; the rest, the holes (0) and the far side of each
    edge are untouched; with none mixed the image is unchanged."""
    depth = np.full((20, 30), 3.0)
    depth[5:15, 10:20] = 2.0
    depth[0, 0] = 0.0
    rng = np.random.default_rng(0)
    assert np.array_equal(mixed_at_edges(depth, 0.0, rng), depth)
    mixed = mixed_at_edges(depth, 1.0, rng)
    rim = np.zeros_like(depth, dtype=bool)
    rim[5:15, 10:20] = True
    rim[6:14, 11:19] = False
    assert np.all((mixed[rim] > 2.0) & (mixed[rim] < 3.0))
    assert np.array_equal(mixed[~rim], depth[~rim])
    half = mixed_at_edges(depth, 0.5, np.random.default_rng(1))
    changed = (half != depth).sum()
    assert 0.3 * rim.sum() < changed < rim.sum()


def test_scenes_with_flying_pixels_are_measured_and_a_bad_share_refused(
    data: Path, tmp_path: Path
) -> None:
    out = tmp_path / "report.json"
    bench_scene.main(["--split", "validation", "--scenes", "2", "--no-large", "--data", str(data),
                      "--cache", str(tmp_path / "cache"), "--flying-pixels", "0.5", "--out",
                      str(out)])  # fmt: skip
    report = json.loads(out.read_text())
    assert report["flying_pixels"] == 0.5 and report["320x240"]["found"]["of"] >= 1
    with pytest.raises(SystemExit) as stopped:
        bench_scene.main(["--split", "validation", "--scenes", "1", "--data", str(data),
                          "--flying-pixels", "1.5"])  # fmt: skip
    assert stopped.value.code == 2


def test_categories_without_scenes_are_refused(data: Path, tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as stopped:
        bench_scene.main(["--split", "validation", "--scenes", "1", "--data", str(data),
                          "--draw", "chair,monitor"])  # fmt: skip
    assert stopped.value.code == 2
    with pytest.raises(SystemExit):
        bench_scene.main(["--split", "validation", "--scenes", "1", "--data", str(data),
                          "--scene-classifier", str(tmp_path / "none.json")])  # fmt: skip


def test_two_runs_compare_object_by_object() -> None:
    """Rows name their scene and object, so two runs on the same scenes pair up; other scenes
    are refused."""
    from benchmarks.compare_scenes import compare

    def obj(scene: int, k: int, right: bool, found: bool = True, named: str | None = "chair"):
        return {"kind": "object", "scene": scene, "object": k, "category": "chair",
                "visible": True, "found": found, "right": right, "predicted": named}  # fmt: skip

    first = [obj(0, 1, True), obj(0, 2, False), obj(1, 1, False, False, None),
             {"kind": "false", "scene": 1, "predicted": "table"}]  # fmt: skip
    second = [obj(0, 2, True), obj(0, 1, True), obj(1, 1, False, True, "sofa"),
              {"kind": "unknown", "scene": 1, "predicted": None},
              {"kind": "distractor", "scene": 0, "predicted": "bed"}]  # fmt: skip
    c = compare(first, second)
    assert c["objects"] == 3
    assert c["right"]["first"] == 33.3 and c["right"]["second"] == 66.7
    assert c["right"]["gain"] == 33.3 and c["right"]["gain_stderr"] == 27.2  # as paired_accuracy
    assert c["found"]["gain"] == 33.3 and c["named"]["gain"] == 0.0
    assert c["false"] == [1, 1] and c["unknown"] == [0, 1]
    with pytest.raises(ValueError, match="same scenes"):
        compare(first, second[:2])
