import numpy as np
import pytest

from itnet.geometry import apply_rigid, random_rotation, rigid_from_rotation_translation
from itnet.preprocess import (
    DegenerateCloudError,
    cap_points,
    estimate_normalization,
    pose_from_normalized,
    pose_to_normalized,
    resample,
    shuffled_subset,
)


def test_normalised_cloud_has_zero_mean_and_unit_rms(rng):
    cloud = rng.normal(size=(300, 3)) * 7 + 100
    x = estimate_normalization(cloud).apply(cloud)
    assert np.allclose(x.mean(0), 0, atol=1e-5)
    assert np.isclose(np.sqrt((x**2).sum(1).mean()), 1, atol=1e-5)


def test_pose_round_trip_and_meaning(rng):
    """A pose in the normalised frame maps normalised points exactly as the input-unit pose maps
    the input points, up to the scale s."""
    cloud = rng.normal(size=(200, 3)) * 3 + 5
    norm = estimate_normalization(cloud)
    pose = rigid_from_rotation_translation(random_rotation(rng), rng.normal(size=3))
    pose_n = pose_to_normalized(pose, norm)
    assert np.allclose(pose_from_normalized(pose_n, norm), pose)
    assert np.allclose(
        apply_rigid(pose_n, norm.apply(cloud)) * norm.scale, apply_rigid(pose, cloud), atol=1e-4
    )


@pytest.mark.parametrize("cloud", [np.zeros((50, 3)), np.full((50, 3), 1e6), np.zeros((0, 3))])
def test_degenerate_cloud_is_refused(cloud):
    with pytest.raises(DegenerateCloudError, match="degenerate"):
        estimate_normalization(cloud)


def test_cap_points_subsamples_large_clouds_and_keeps_small_ones_whole(rng):
    cloud = rng.normal(size=(100, 3))
    assert np.array_equal(cap_points(cloud, 100, rng), cloud)
    assert np.array_equal(cap_points(cloud, 1000, rng), cloud)
    out = cap_points(cloud, 30, rng)
    assert out.shape == (30, 3) and len({tuple(p) for p in out}) == 30
    assert {tuple(p) for p in out} <= {tuple(p) for p in cloud}
    seeded = [cap_points(cloud, 30, np.random.default_rng(5)) for _ in range(2)]
    assert np.array_equal(*seeded)


def test_shuffled_subset_is_random_in_order_as_well_as_in_choice(rng):
    cloud = np.arange(300, dtype=float)[:, None] * [1.0, 0.0, 0.0]  # rows in scan order
    small = shuffled_subset(cloud[:100], 256, rng)
    assert sorted(small[:, 0]) == list(range(100))  # every point, once
    assert not np.array_equal(small, cloud[:100])  # but not in the scan's order
    assert small[:25, 0].max() > 50  # the first points reach across the cloud
    large = shuffled_subset(cloud, 64, rng)
    assert large.shape == (64, 3) and len(set(large[:, 0])) == 64
    seeded = [shuffled_subset(cloud[:100], 256, np.random.default_rng(5)) for _ in range(2)]
    assert np.array_equal(*seeded)


def test_resample_exact_count_without_inventing_points(rng):
    cloud = rng.normal(size=(100, 3))
    for n in (10, 100, 1000):
        out = resample(cloud, n, rng)
        assert out.shape == (n, 3)
        assert {tuple(p) for p in out} <= {tuple(p) for p in cloud}
    assert len({tuple(p) for p in resample(cloud, 1000, rng)}) == 100  # every point kept
