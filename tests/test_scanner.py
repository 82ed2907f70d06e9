import numpy as np

from itnet.geometry import apply_rigid, invert_rigid
from itnet.model.scanner import ScanConfig, random_camera_pose, scan_shape, zbuffer_scan


def _sphere(rng, n=4000):
    p = rng.normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def test_zbuffer_keeps_the_near_side_in_the_camera_frame(rng):
    pts = _sphere(rng)
    cam = random_camera_pose(rng, ScanConfig())
    seen = zbuffer_scan(pts, cam, pixel=0.05)
    assert 0.2 * len(pts) < len(seen) < 0.65 * len(pts)
    assert seen[:, 2].min() > 0  # in front of the camera
    # Every kept point faces the camera: its normal (the point itself on a sphere) points back.
    canonical = apply_rigid(invert_rigid(cam), seen)
    camera_centre = invert_rigid(cam)[:3, 3]
    facing = np.einsum("ij,ij->i", canonical, camera_centre - canonical)
    assert (facing > -0.1).mean() > 0.97


def test_scan_label_maps_the_scan_back_onto_the_shape(rng):
    shape = _sphere(rng) * [1.0, 0.6, 0.3]
    config = ScanConfig(depth_noise=(0, 0), jitter=(0, 0), outlier_fraction=(0, 0))
    for _ in range(5):
        cloud, pose = scan_shape(shape, rng, config)
        back = apply_rigid(pose, cloud)
        d = np.linalg.norm(back[:, None] - shape[None], axis=-1).min(1)
        assert d.max() < 1e-9  # exactly points of the shape, expressed in the camera frame
        assert np.linalg.norm(cloud.mean(0)) > 1.0  # and the camera frame is not the canonical one


def test_mesh_raycast_scan_lies_on_the_mesh(rng):
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_box(1.0, 0.5, 0.25).translate([-0.5, -0.25, -0.125])
    vertices = np.asarray(mesh.vertices) / np.linalg.norm(np.asarray(mesh.vertices), axis=1).max()
    config = ScanConfig(depth_noise=(0, 0), jitter=(0, 0), outlier_fraction=(0, 0))
    cloud, pose = scan_shape(vertices, rng, config, np.asarray(mesh.triangles))
    back = apply_rigid(pose, cloud)
    half = np.abs(vertices).max(0)
    on_face = np.isclose(np.abs(back), half, atol=1e-4).any(axis=1)
    assert len(cloud) > 500 and on_face.all() and (np.abs(back) <= half + 1e-4).all()


def test_cameras_above_the_horizon_stay_within_their_elevation_and_see_the_object(rng):
    """``elevation``: every camera sits 10-40 degrees over the canonical horizon (+y up), whatever
    the object's offset from the optical axis, and the object's centre is where the pose says."""
    config = ScanConfig(elevation=(10.0, 40.0))
    elevations = []
    for _ in range(300):
        camera_from_canonical = random_camera_pose(rng, config)
        rotation = camera_from_canonical[:3, :3]
        assert np.allclose(rotation @ rotation.T, np.eye(3)) and np.linalg.det(rotation) > 0
        centre = invert_rigid(camera_from_canonical)[:3, 3]  # the camera in the canonical frame
        elevations.append(np.degrees(np.arcsin(centre[1] / np.linalg.norm(centre))))
        assert camera_from_canonical[2, 3] > 0  # the object ahead of the camera
    assert 10.0 - 1e-6 <= min(elevations) < 15.0 and 35.0 < max(elevations) <= 40.0 + 1e-6


def test_a_camera_above_sees_the_upper_side(rng):
    """A sphere seen from 20-50 degrees over its horizon shows the side that faces the camera:
    the seen points lie above the centre, by about sin(elevation) / 2 of the radius."""
    config = ScanConfig(elevation=(20.0, 50.0), depth_noise=(0, 0), jitter=(0, 0),
                        outlier_fraction=(0, 0))  # fmt: skip
    sphere = _sphere(rng)
    for _ in range(5):
        cloud, pose = scan_shape(sphere, rng, config)
        heights = apply_rigid(pose, cloud)[:, 1]
        assert 0.1 < heights.mean() < 0.45


def test_a_level_views_bottom_edge_hides_the_base(rng):
    """Views with the base below the view (BASE_HIDDEN): the cut is a plane through the camera,
    level across the view, through the object's centre line at the drawn height, so a point on
    that line is seen exactly where it stands above the height; the camera looks down on it."""
    from itnet.model.scanner import BASE_HIDDEN, below_view_edge, scan_config

    config = scan_config(BASE_HIDDEN)
    line = np.stack([np.zeros(41), np.linspace(-1.0, 1.0, 41), np.zeros(41)], 1)
    for _ in range(20):
        cam = random_camera_pose(rng, config)
        height = rng.uniform(*config.cut_below)
        seen = below_view_edge(apply_rigid(cam, line), cam, height)
        np.testing.assert_array_equal(seen, line[:, 1] >= height - 1e-9)
    shape = _sphere(rng)
    whole = ScanConfig(depth_noise=(0, 0), jitter=(0, 0), outlier_fraction=(0, 0))
    cut = scan_config(whole.__dict__, {"cut_below": (-0.2, -0.2), "elevation": (20.0, 20.0)})
    lows = []
    for kind in (whole, cut):
        cloud, pose = scan_shape(shape, rng, kind)
        lows.append(apply_rigid(pose, cloud)[:, 1].min())
    assert lows[0] < -0.8 and -0.6 < lows[1] < -0.2  # the far side is cut lower than the near
