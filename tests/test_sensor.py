"""The sensor model of virtual scans: what each camera preset does to a surface it sees, in
metres, and scans of real-sized objects through it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from itnet.model.categories import MODELNET10, REAL_RADIUS_M
from itnet.model.scanner import scan_config, scan_shape, sensor_views
from itnet.model.sensor import SENSORS, incidence, silhouette


def wall(depth_m: float, tilt_deg: float = 0.0, size: float = 0.6, n: int = 3000) -> np.ndarray:
    """Points of a square patch ``size`` m wide, ``depth_m`` ahead, turned ``tilt_deg`` about
    the camera's y axis (0: facing the camera)."""
    rng = np.random.default_rng(0)
    u, v = rng.uniform(-size / 2, size / 2, (2, n))
    t = np.radians(tilt_deg)
    return np.stack([u * np.cos(t), v, depth_m + u * np.sin(t)], axis=1)


def test_clean_returns_the_scan_as_it_is() -> None:
    points = wall(2.0)
    np.testing.assert_array_equal(SENSORS["clean"].apply(points, np.random.default_rng(1)), points)


@pytest.mark.parametrize("name", ["kinect_v1", "kinect_v2", "realsense_d435"])
def test_depth_noise_grows_with_depth(name: str) -> None:
    sensor = dataclasses.replace(SENSORS[name], flying_share=0.0)  # the noise alone
    spread = []
    for depth in (1.0, 3.5):
        seen = sensor.apply(wall(depth), np.random.default_rng(2))
        spread.append(float(np.std(seen[:, 2])))
    assert spread[1] > 1.5 * spread[0] > 0


def test_structured_light_depth_lies_on_disparity_steps() -> None:
    sensor = SENSORS["kinect_v1"]
    seen = sensor.apply(wall(3.0), np.random.default_rng(3))
    levels, counts = np.unique(np.round(seen[:, 2], 4), return_counts=True)
    main = levels[counts > 0.02 * len(seen)]  # the levels most points sit on
    step = main[0] ** 2 / (sensor.focal_px * sensor.baseline_m) * sensor.disparity_step_px
    assert 2 <= len(main) <= 8  # a flat wall at 3 m: a few levels, 2.6 cm apart
    np.testing.assert_allclose(np.diff(main), step, rtol=0.15)


def test_a_grazing_surface_and_a_far_one_return_less() -> None:
    rng = np.random.default_rng(4)
    sensor = SENSORS["kinect_v2"]
    facing = len(sensor.apply(wall(2.0, 0.0), rng))
    grazing = len(sensor.apply(wall(2.0, 84.0), rng))
    far = len(sensor.apply(wall(7.5), rng))
    assert grazing < 0.5 * facing and far < 0.5 * facing
    assert facing > 0.8 * 3000


def test_time_of_flight_edges_fly_behind_the_surface() -> None:
    seen = SENSORS["kinect_v2"].apply(wall(2.0), np.random.default_rng(5))
    behind = seen[:, 2] > 2.0 + 0.04
    assert 0.005 * len(seen) < behind.sum() < 0.2 * len(seen)
    assert silhouette(wall(2.0)).mean() < 0.2


def test_incidence_is_the_angle_of_the_surface_to_the_ray() -> None:
    angles = np.degrees(incidence(wall(2.0, 60.0, size=0.2)))
    assert abs(float(np.median(angles)) - 60.0) < 5.0


def test_scans_of_real_sized_objects_are_seeded_and_in_object_radii() -> None:
    rng = np.random.default_rng(6)
    box = rng.uniform(-1, 1, (3000, 3))
    face = rng.integers(0, 3, 3000)
    box[np.arange(3000), face] = np.sign(box[np.arange(3000), face])
    box *= [0.6, 0.8, 0.4]
    config = scan_config(sensor_views("kinect_v1", REAL_RADIUS_M["chair"]))
    a = scan_shape(box, np.random.default_rng(7), config)
    b = scan_shape(box, np.random.default_rng(7), config)
    np.testing.assert_array_equal(a[0], b[0])
    clean = scan_shape(
        box, np.random.default_rng(7), scan_config(sensor_views("clean", (0.5, 0.5)))
    )
    centre = a[1][:3, :3] @ a[0].mean(0) + a[1][:3, 3]  # the scan's mean in canonical
    assert np.linalg.norm(centre) < 1.0  # in object radii, on the object
    assert len(a[0]) < len(clean[0])
    with pytest.raises(ValueError, match="unknown sensor"):
        sensor_views("kinect_v9", (0.5, 0.5))


def test_every_category_has_real_sizes() -> None:
    assert set(REAL_RADIUS_M) == set(MODELNET10)
    assert all(0.2 < lo <= hi < 2.0 for lo, hi in REAL_RADIUS_M.values())


def test_the_commands_take_a_camera_by_name_and_refuse_unknown_ones(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from typer.testing import CliRunner

    from itnet.cli import app
    from itnet.model.scanner import named_overrides

    assert named_overrides("paper+kinect_v1", "bed")["radius_m"] == REAL_RADIUS_M["bed"]
    assert "sensor" not in named_overrides("occluded", "bed")
    runner = CliRunner()
    result = runner.invoke(app, ["train", "--sensors", "kinect_v9", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "unknown sensor 'kinect_v9'" in result.output
    result = runner.invoke(app, ["train", "--val-scanner", "sideways", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "unknown view rule 'sideways'" in result.output
    result = runner.invoke(app, ["eval", "--onnx", "itnet/models/chair.onnx", "--scanner",
                                 "occluded+kinect_v9", "--out", str(tmp_path)])  # fmt: skip
    assert result.exit_code == 2 and "unknown sensor" in result.output


def plane_image(depth_m: float, tilt_deg: float = 0.0, size: int = 120) -> np.ndarray:
    """A depth image (size, size) of a plane ``depth_m`` ahead at the centre, turned
    ``tilt_deg`` about the camera's y axis (focal FOCAL)."""
    u = (np.arange(size) - size / 2) / FOCAL[0]
    t = np.tan(np.radians(tilt_deg))
    row = depth_m / (1 - u * t)  # z along each column's ray on the turned plane
    return np.tile(row, (size, 1))


FOCAL = (100.0, 100.0, 60.0, 60.0)


def test_a_depth_image_is_seen_through_the_same_camera() -> None:
    image = plane_image(2.0)
    clean = SENSORS["clean"].apply_to_depth(image, FOCAL, np.random.default_rng(0))
    np.testing.assert_array_equal(clean, image)
    sensor = dataclasses.replace(SENSORS["kinect_v2"], flying_share=0.0, holes=(0, 0))
    spread = []
    for depth in (1.0, 4.0):
        seen = sensor.apply_to_depth(plane_image(depth), FOCAL, np.random.default_rng(1))
        assert (seen > 0).mean() > 0.9
        spread.append(float(np.std(seen[seen > 0])))
    assert spread[1] > 1.5 * spread[0] > 0  # noise grows with depth
    facing = (sensor.apply_to_depth(plane_image(2.0), FOCAL, np.random.default_rng(2)) > 0).mean()
    grazing = sensor.apply_to_depth(plane_image(2.0, 84.0), FOCAL, np.random.default_rng(2))
    far = sensor.apply_to_depth(plane_image(7.5), FOCAL, np.random.default_rng(2))
    assert (grazing > 0).mean() < 0.5 * facing and (far > 0).mean() < 0.5 * facing
    holed = dataclasses.replace(sensor, holes=(2, 2), hole_radius_m=(0.1, 0.1))
    assert (holed.apply_to_depth(plane_image(2.0), FOCAL, np.random.default_rng(3)) > 0).mean() < (
        facing - 0.02
    )
    levels = SENSORS["kinect_v1"].apply_to_depth(plane_image(3.0), FOCAL, np.random.default_rng(4))
    assert len(np.unique(np.round(levels[levels > 0], 4))) < 12  # on disparity steps
