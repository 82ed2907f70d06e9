"""Complete shapes in the canonical frame: loading, frame mapping, orientation checks.

Canonical frame (SPEC.md, ShapeNetCore v2): +y up, the object's front toward -z (a chair's back
on +z), origin at the bounding-box centre, bounding-sphere radius 1 about that centre.

Source frames a folder can be in (``--frame``):

* ``canonical``: already +y up, front -z (only centred and scaled here).
* ``modelnet``: ModelNet's +z up, back on +y. ``(x, y, z) -> (-x, z, y)`` maps it (det +1).
* ``z-up``: +z up, front toward -y (common in robotics/CAD): ``(x, y, z) -> (x, z, -y)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.cloud_io import SUFFIXES as CLOUD_SUFFIXES
from itnet.cloud_io import read_cloud
from itnet.geometry import axis_angle_to_matrix
from itnet.model.surface import surface_discs

MESH_SUFFIXES = (".obj", ".off", ".stl", ".glb", ".gltf")
FRAME_ROTATIONS: dict[str, NDArray[np.float64]] = {
    "canonical": np.eye(3),
    "modelnet": np.array([[-1.0, 0, 0], [0, 0, 1], [0, 1, 0]]),
    "z-up": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
}


@dataclass
class Shape:
    """A complete object in the canonical frame (unit bounding sphere about the bbox centre).

    ``points`` (M, 3) always; ``triangles`` (F, 3) when the source was a mesh.
    """

    name: str
    points: NDArray[np.float64]
    triangles: NDArray[np.int64] | None = None
    notes: list[str] = field(default_factory=list)
    _discs: tuple[NDArray[np.float64], NDArray[np.float64]] | None = field(
        default=None, repr=False, compare=False
    )

    def discs(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The points' surface discs (normals (M, 3), spacing (M,); ``surface.surface_discs``),
        computed on first use and kept: surface views of a shape reuse them every scan."""
        if self._discs is None:
            self._discs = surface_discs(self.points)
        return self._discs


def to_canonical(points: NDArray, frame: str) -> tuple[NDArray[np.float64], float]:
    """Points (M, 3) in a named source frame -> (canonical points (M, 3), source radius)."""
    p = np.asarray(points, dtype=np.float64) @ FRAME_ROTATIONS[frame].T
    center = (p.min(0) + p.max(0)) / 2
    radius = float(np.linalg.norm(p - center, axis=1).max())
    if radius <= 0:
        raise ValueError("the shape has no extent")
    return (p - center) / radius, radius


def load_shape(path: Path, frame: str, quarter_turns: int = 0) -> Shape:
    """Read a mesh (ray-castable) or a point cloud file as a canonical Shape, mapped from
    ``frame`` and then turned by ``quarter_turns`` x 90 degrees about +y (a category's turn,
    ``model.categories``)."""
    shape = _load_shape(path, frame)
    if quarter_turns % 4:
        shape.points = shape.points @ yaw_rotation(quarter_turns).T
    return shape


def _load_shape(path: Path, frame: str) -> Shape:
    if path.suffix.lower() in MESH_SUFFIXES or _is_mesh_ply(path):
        import open3d as o3d

        mesh = o3d.io.read_triangle_mesh(str(path))
        vertices = np.asarray(mesh.vertices)
        if len(mesh.triangles) == 0:
            raise ValueError(f"{path}: a mesh without triangles")
        canonical, _ = to_canonical(vertices, frame)
        return Shape(path.stem, canonical, np.asarray(mesh.triangles, dtype=np.int64))
    canonical, _ = to_canonical(read_cloud(path), frame)
    return Shape(path.stem, canonical)


def random_stretch(rng: np.random.Generator, spread: float) -> NDArray[np.float64]:
    """Factors (3,) for ``stretched``, each log-uniform in [1/spread, spread] (1: none)."""
    return np.asarray(spread, dtype=np.float64) ** rng.uniform(-1.0, 1.0, size=3)


def stretched(shape: Shape, factors: NDArray) -> Shape:
    """The shape scaled by ``factors`` (3,) along its canonical axes, then back to the unit
    bounding sphere: another plausible member of its class (a wider sofa, a taller night stand)
    in the same frame, for training on more shapes than the dataset has. The bounding box stays
    centred on the origin, so the pose of a view of it is the pose of a view of the original.

    Triangles keep their indices. Surface discs already computed for ``shape`` are carried over
    exactly: under ``A = diag(factors) / r`` a normal becomes ``A⁻ᵀn`` (normalised) and a disc's
    area scales by ``det(A) |A⁻ᵀn|``, so its spacing by the square root of that; otherwise they
    are computed on first use, as for any shape."""
    f = np.asarray(factors, dtype=np.float64)
    if f.shape != (3,) or not np.all(f > 0):
        raise ValueError(f"stretch factors must be 3 positive numbers, got {factors!r}")
    points = shape.points * f
    radius = float(np.linalg.norm(points, axis=1).max())
    if radius <= 0:
        raise ValueError("the shape has no extent")
    out = Shape(shape.name, points / radius, shape.triangles, list(shape.notes))
    if shape._discs is not None:
        a = f / radius
        normals, spacing = shape._discs
        moved = normals / a
        length = np.linalg.norm(moved, axis=1)
        out._discs = (moved / length[:, None], spacing * np.sqrt(np.prod(a) * length))
    return out


def _is_mesh_ply(path: Path) -> bool:
    if path.suffix.lower() != ".ply":
        return False
    with path.open("rb") as f:
        head = f.read(4096)
    return b"element face" in head and b"element face 0" not in head


def list_shape_files(folder: Path) -> list[Path]:
    """Mesh and cloud files below a folder, sorted (so a seed gives the same split everywhere)."""
    suffixes = set(MESH_SUFFIXES) | set(CLOUD_SUFFIXES)
    return sorted(p for p in folder.rglob("*") if p.suffix.lower() in suffixes and p.is_file())


def yaw_rotation(quarter_turns: int) -> NDArray[np.float64]:
    """Rotation by a multiple of 90 degrees about the canonical up axis (+y)."""
    return axis_angle_to_matrix([0.0, 1.0, 0.0], quarter_turns * np.pi / 2)


def chamfer(a: NDArray, b: NDArray) -> float:
    """Symmetric mean nearest-neighbour distance between point sets (M, 3) and (K, 3)."""
    d = np.sum(a * a, 1)[:, None] + np.sum(b * b, 1)[None, :] - 2 * a @ b.T
    return float(np.sqrt(np.maximum(d.min(1), 0)).mean() + np.sqrt(np.maximum(d.min(0), 0)).mean())


def check_yaw(
    shapes: list[Shape],
    seed: int = 0,
    references: int = 24,
    sample: int = 256,
    margin: float = 0.05,
    symmetry: str = "none",
) -> tuple[list[Shape], dict[str, int]]:
    """Find shapes turned by a multiple of 90 degrees about up, against the rest of their class.

    For each shape, the quarter-turns that the category's ``symmetry`` tells apart (four for
    ``none``; 0 and 90 degrees for ``yaw180``, where 180 is the same pose; none for ``yaw90`` and
    ``yaw``, which return the shapes as they are) are scored by the median Chamfer distance to a random
    set of reference shapes of the class (most of which are right). A shape the references
    clearly prefer turned (its best turn is not 0 and beats no turn by the relative ``margin``) is
    turned back; a shape whose best turn is not 0 but not clearly (the references are split) is
    dropped, its label in doubt; every other shape is kept as the dataset has it (a shape whose
    turns all score alike gives no evidence against its label). Returns (kept shapes, counts).
    """
    candidates = {"none": 4, "yaw180": 2}.get(symmetry, 1)
    if candidates == 1:
        return list(shapes), {"kept": len(shapes), "turned": 0, "dropped": 0}
    rng = np.random.default_rng(seed)
    subsample = [
        s.points[rng.choice(len(s.points), min(sample, len(s.points)), replace=False)]
        for s in shapes
    ]
    refs = rng.choice(len(shapes), size=min(references, len(shapes)), replace=False)
    kept, counts = [], {"kept": 0, "turned": 0, "dropped": 0}
    turns = [yaw_rotation(k) for k in range(candidates)]
    for i, shape in enumerate(shapes):
        scores = []
        for r in turns:
            moved = subsample[i] @ r.T
            scores.append(np.median([chamfer(moved, subsample[j]) for j in refs if j != i]))
        k = int(np.argmin(scores))
        if k != 0 and scores[0] - scores[k] < margin * scores[k]:
            counts["dropped"] += 1
            continue
        if k != 0:
            shape = Shape(
                shape.name,
                shape.points @ turns[k].T,
                shape.triangles,
                [*shape.notes, f"turned {90 * k} deg about up"],
            )
            counts["turned"] += 1
        else:
            counts["kept"] += 1
        kept.append(shape)
    return kept, counts
