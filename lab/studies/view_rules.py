"""What each view rule lets a camera see of a sparse point set: the share of points kept, by how
squarely they face the camera, for 1,024 points on a unit sphere (the spacing of a ModelNet10
shape) under the project's random viewpoints.

    python -m lab.studies.view_rules [--views 50] [--seed 0]

A depth camera looking at the sphere's surface sees the near half (facing > 0, less the grazing
band) and nothing of the far half (facing < 0). Prints one row per rule and pixel size: the
share kept in each facing bin (cosine between the surface normal and the direction to the
camera, −1 … 1 in tenths), and the points per scan. Deterministic for a seed.
"""

from __future__ import annotations

import argparse

import numpy as np

from itnet.geometry import apply_rigid, invert_rigid
from itnet.model.scanner import (
    VIEW_RULES,
    ScanConfig,
    random_camera_pose,
    scan_config,
    zbuffer_visible,
)
from itnet.model.surface import splat_visible, surface_discs

BINS = 10


def kept_by_facing(rule: str, pixel: float, views: int, seed: int) -> tuple[np.ndarray, float]:
    """Share of points kept per facing bin (BINS,), and the mean points per scan."""
    rng = np.random.default_rng(seed)
    sphere = rng.normal(size=(1024, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    normals, spacing = surface_discs(sphere)
    config = scan_config(VIEW_RULES[rule])
    kept, total, counts = np.zeros(BINS), np.zeros(BINS), []
    for _ in range(views):
        camera = random_camera_pose(rng, ScanConfig())
        points = apply_rigid(camera, sphere)
        if config.splat > 0:
            normals_cam = normals @ camera[:3, :3].T
            seen = splat_visible(
                points, normals_cam, config.splat * spacing, pixel, config.tolerance
            )
        else:
            seen = zbuffer_visible(points, pixel, config.tolerance, config.occlusion_tolerance)
        to_camera = invert_rigid(camera)[:3, 3] - sphere
        facing = np.einsum(
            "ij,ij->i", sphere, to_camera / np.linalg.norm(to_camera, axis=1)[:, None]
        )
        bins = np.clip(((facing + 1) / 2 * BINS).astype(int), 0, BINS - 1)
        np.add.at(kept, bins, seen)
        np.add.at(total, bins, 1)
        counts.append(seen.sum())
    return kept / total, float(np.mean(counts))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--views", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    edges = np.linspace(-1, 1, BINS + 1)
    header = " ".join(f"{a:+.1f}..{b:+.1f}" for a, b in zip(edges[:-1], edges[1:]))
    print(f"kept share by facing (1,024-point unit sphere, {args.views} views per row)")
    print(f"{'rule':>9} {'pixel':>5} | {header} | points/scan")
    for rule in VIEW_RULES:
        for pixel in (0.035, 0.07):
            share, points = kept_by_facing(rule, pixel, args.views, args.seed)
            row = " ".join(f"{100 * s:9.0f}" for s in share)
            print(f"{rule:>9} {pixel:5.3f} | {row} | {points:.0f}")


if __name__ == "__main__":
    main()
