import json

import numpy as np
import pytest

from itnet.scene import Intrinsics, SceneInputError, intrinsics_from_json, parse_intrinsics
from itnet.scene.camera import depth_to_cloud


def test_depth_to_cloud_back_projects_each_pixel_with_the_intrinsics():
    intrinsics = Intrinsics(500.0, 400.0, 2.0, 1.0)
    depth = np.zeros((3, 4))
    depth[0, 0], depth[2, 3], depth[1, 2] = 2.0, 4.0, 1.0
    points, pixels = depth_to_cloud(depth, intrinsics)
    assert pixels.tolist() == [0, 6, 11]  # row-major v * W + u
    expected = [[(0 - 2) * 2.0 / 500, (0 - 1) * 2.0 / 400, 2.0],
                [0.0, 0.0, 1.0],
                [(3 - 2) * 4.0 / 500, (2 - 1) * 4.0 / 400, 4.0]]  # fmt: skip
    np.testing.assert_allclose(points, expected)
    # projecting back gives the pixels
    u = intrinsics.fx * points[:, 0] / points[:, 2] + intrinsics.cx
    v = intrinsics.fy * points[:, 1] / points[:, 2] + intrinsics.cy
    np.testing.assert_allclose(v * 4 + u, pixels)


def test_depth_to_cloud_skips_missing_and_far_readings():
    depth = np.array([[0.0, np.nan, 30.0, 1.5]])
    points, pixels = depth_to_cloud(depth, Intrinsics(1, 1, 0, 0), max_depth_m=20.0)
    assert pixels.tolist() == [3] and points.shape == (1, 3)


def test_the_three_json_forms_give_the_same_intrinsics(tmp_path):
    want = Intrinsics(525.0, 520.0, 319.5, 239.5)
    plain = {"fx": 525.0, "fy": 520.0, "cx": 319.5, "cy": 239.5}
    ros = {"K": [525.0, 0, 319.5, 0, 520.0, 239.5, 0, 0, 1], "width": 640, "height": 480}
    ros2 = {"k": ros["K"]}
    open3d = {"width": 640, "height": 480,
              "intrinsic_matrix": [525.0, 0, 0, 0, 520.0, 0, 319.5, 239.5, 1]}  # fmt: skip
    for data in (plain, ros, ros2, open3d):
        assert intrinsics_from_json(data) == want
        path = tmp_path / "camera.json"
        path.write_text(json.dumps(data))
        assert parse_intrinsics(str(path)) == want
    assert parse_intrinsics("525,520,319.5,239.5") == want


@pytest.mark.parametrize("text", ["1,2,3", "a,b,c,d", "0,1,1,1", "/no/such/camera.json"])
def test_bad_intrinsics_say_what_is_wrong(text):
    with pytest.raises(SceneInputError):
        parse_intrinsics(text)


def test_intrinsics_json_without_a_camera_is_refused():
    with pytest.raises(SceneInputError, match="fx, fy, cx, cy"):
        intrinsics_from_json({"width": 640})
