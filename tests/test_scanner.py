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
