"""Categories: each one's canonical frame (from ModelNet10's) and its symmetry, and how both were
decided from the shapes.

Canonical frame (SPEC.md): +y up, the object's front toward -z; a bed's head end on +z; a
category without a front has its longest horizontal extent along x. ModelNet10's files go
through the chair's mapping ``(x, y, z) -> (-x, z, y)`` (``shapes.FRAME_ROTATIONS['modelnet']``),
then a per-class number of quarter turns about +y (``quarter_turns``), measured on the training
split (``itnet fit categories``):

* chair, bed, toilet: the back (headboard, tank) is the upper part and leans to +z for 95-100%:
  no turn.
* sofa, desk, monitor: the long axis comes out along z and the front faces +x (a sofa's back
  leans to -x for 99%; a desk's mass, hutch and back panel sit at -x for 85%; a CRT's tube and a
  flat panel's neck are behind the screen, at -x): a +90 degree turn puts the back on +z.
* bathtub, table, dresser, night_stand: front and back alike at scan resolution (``yaw180``), the
  long axis along z: a quarter turn puts it along x.

Symmetry is measured per shape: the Chamfer distance between two random 400-point samples of a
shape (disjoint halves of its points), one turned by 90, by 180 and by a random other angle about
up, over the distance between the two unturned halves (the sampling floor). A class whose median ratio for a turn is below
``SYMMETRY_RATIO`` looks alike under that turn. The mirror planes (``Category.mirror_planes``,
which ``itnet.mirror`` uses to finish a pose) are measured alike, with one half reflected in
x = 0 (left-right) or z = 0 (front-back) instead of turned. x = 0: 0.81-0.88 for nine classes (a
reflected half lies as near as the other half); the desk's ranges from 1.01 to 1.24 with the
sample of shapes (many desks have their drawers on one side), so it is not declared. z = 0:
0.86-0.89 for the four ``yaw180`` classes (front and back alike), which declare it; 1.11 and
more for the others (the bed's head end, the chair's back).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from itnet.geometry import axis_angle_to_matrix
from itnet.model.shapes import Shape, chamfer
from itnet.symmetry import SYMMETRY_NAMES

# A turn is a symmetry when a turned half of a shape lies within 10% of the sampling floor.
SYMMETRY_RATIO = 1.10


@dataclass(frozen=True)
class Category:
    """How a category's files map to its canonical frame, and its symmetry."""

    name: str
    quarter_turns: int = 0  # turns of +90 degrees about +y after the source frame's mapping
    symmetry: str = "none"
    # canonical planes of mirror symmetry: 'x' (x = 0, left-right), 'z' (z = 0, front-back)
    mirror_planes: tuple[str, ...] = ()
    # the turns about up a partial view of it is often mistaken by (a symmetry group's name, at
    # least its ``symmetry``): a chair's seat is nearly square, so a view of it is often
    # explained as well by a quarter turn. The alignment tries them as rivals.
    confusions: str = "yaw180"
    # (small, large) real bounding radius in metres (``REAL_RADIUS_M``)
    real_radius_m: tuple[float, float] = (0.5, 0.5)
    # (median, robust spread of its log) of its height in metres on ModelNet10's training
    # shapes (``itnet.scene.height_prior``); None: unknown
    height_m: tuple[float, float] | None = None
    # in the development scenes: (which extent: 'height' or 'length', its range in metres)
    # (``itnet.model.scenes``); None: not on a scene's floor
    scene_size: tuple[str, tuple[float, float]] | None = None
    # the category's pose model is trained upright and served only with the up direction given:
    # without it, views of it are ambiguous (a box on its side); its card says requires_up
    requires_up: bool = False

    def __post_init__(self) -> None:
        for name in (self.symmetry, self.confusions):
            if name not in SYMMETRY_NAMES:
                raise ValueError(f"unknown symmetry {name!r}")


MODELNET10: dict[str, Category] = {
    c.name: c
    for c in (
        Category("bathtub", 1, "yaw180", ("x", "z"),
                 # 0.9 x 0.5 x 0.6 m (a small tub) to 1.8 x 0.6 x 0.9 m
                 real_radius_m=(0.55, 1.05), height_m=(0.63, 0.34),
                 scene_size=("length", (1.5, 1.8))),
        Category("bed", 0, "none", ("x",),
                 # single 0.9 x 1.0 x 2.0 m (with headboard) to king 1.9 x 1.2 x 2.2 m
                 real_radius_m=(1.1, 1.6), height_m=(1.0, 0.39),
                 scene_size=("length", (1.9, 2.1))),
        Category("chair", 0, "none", ("x",), confusions="yaw90",
                 # 0.42 x 0.78 x 0.45 m to an armchair's 0.65 x 1.1 x 0.7 m
                 real_radius_m=(0.48, 0.75), height_m=(0.94, 0.21),
                 scene_size=("height", (0.8, 1.0))),
        Category("desk", 1, "none",  # mirror ratio 1.01-1.24 by sample: drawers on one side
                 # 1.0 x 0.72 x 0.5 m to 1.8 x 0.76 x 0.9 m
                 real_radius_m=(0.65, 1.1), height_m=(0.76, 0.09),
                 scene_size=("length", (1.0, 1.6)), requires_up=True),
        Category("dresser", 1, "yaw180", ("x", "z"), confusions="yaw90",
                 # 0.8 x 0.75 x 0.45 m to 1.6 x 1.1 x 0.55 m
                 real_radius_m=(0.58, 1.0), height_m=(0.99, 0.37),
                 scene_size=("height", (0.8, 1.2)), requires_up=True),
        Category("monitor", 1, "none", ("x",),
                 # 0.45 x 0.35 x 0.18 m to 0.85 x 0.6 x 0.25 m, stand included
                 real_radius_m=(0.28, 0.55), height_m=(0.5, 0.47), requires_up=True),
        Category("night_stand", 1, "yaw180", ("x", "z"), confusions="yaw90",
                 # 0.4 x 0.5 x 0.35 m to 0.6 x 0.75 x 0.5 m
                 real_radius_m=(0.35, 0.55), height_m=(0.66, 0.18),
                 scene_size=("height", (0.5, 0.65)), requires_up=True),
        Category("sofa", 1, "none", ("x",),
                 # a two-seater 1.4 x 0.8 x 0.8 m to 2.5 x 0.95 x 1.0 m
                 real_radius_m=(0.85, 1.45), height_m=(0.83, 0.18),
                 scene_size=("length", (1.7, 2.2))),
        Category("table", 1, "yaw180", ("x", "z"), confusions="yaw90",
                 # a coffee table 0.9 x 0.45 x 0.5 m to a dining table 2.0 x 0.76 x 1.0 m
                 real_radius_m=(0.55, 1.2), height_m=(0.73, 0.27),
                 scene_size=("length", (1.0, 1.8))),
        Category("toilet", 0, "none", ("x",),
                 # 0.36 x 0.7 x 0.6 m to 0.45 x 0.85 x 0.75 m
                 real_radius_m=(0.48, 0.62), height_m=(0.77, 0.25),
                 scene_size=("height", (0.7, 0.8))),
    )
}  # fmt: skip
"""Every fact about a ModelNet10 category, in one place: its frame's turn, symmetry, mirror
planes, the turns its views are mistaken by, its real sizes, its height and its size in the
development scenes (see ``Category``)."""

REAL_RADIUS_M: dict[str, tuple[float, float]] = {
    name: c.real_radius_m for name, c in MODELNET10.items()
}
"""Per category, the bounding radius (half the box's diagonal) of small and large real pieces,
width x height x depth as furniture is made (Neufert, Architects' Data, 4th ed., 2012; Panero
and Zelnik, Human Dimension and Interior Space, 1979; docs/training.md#real-sizes). A user's
category without an entry is taken as 0.5 m."""


def real_radius_m(name: str) -> tuple[float, float]:
    """The range of real bounding radii of a category's pieces, in metres."""
    return REAL_RADIUS_M.get(name, (0.5, 0.5))


def category(name: str, symmetry: str | None = None) -> Category:
    """The ModelNet10 entry for ``name``, or a user's category (no turn) with ``symmetry``."""
    known = MODELNET10.get(name, Category(name))
    if symmetry is None or symmetry == "auto":
        return known
    return Category(name, known.quarter_turns, symmetry, known.mirror_planes)


def model_category(requested: str | None, trained_on: str, symmetry: str | None) -> Category:
    """The category a model answers for: ``requested``, else the one it was trained on; a
    network trained on several ('a,b' or 'modelnet10') must be told which (ValueError)."""
    if requested is None and ("," in trained_on or trained_on == "modelnet10"):
        raise ValueError(f"the model knows several categories ({trained_on}): --category")
    return category(requested or trained_on, symmetry)


def self_match_ratios(
    shapes: list[Shape], rng: np.random.Generator, sample: int = 400
) -> dict[str, float]:
    """Median over shapes of Chamfer(half, turned other half) / Chamfer(half, other half)
    for turns of 90 and 180 degrees and a random angle in (17, 70) degrees, and with the other
    half reflected in x = 0 ('mirror_x') or in z = 0 ('mirror_z')."""
    ratios: dict[str, list[float]] = {
        "yaw90": [], "yaw180": [], "yaw": [], "mirror_x": [], "mirror_z": []
    }  # fmt: skip
    for shape in shapes:
        order = rng.permutation(len(shape.points))  # two disjoint halves: independent samples
        n = min(sample, len(order) // 2)
        a, b = shape.points[order[:n]], shape.points[order[n : 2 * n]]
        floor = max(chamfer(a, b), 1e-9)
        for key, angle in (("yaw90", 90.0), ("yaw180", 180.0), ("yaw", rng.uniform(17, 70))):
            turn = axis_angle_to_matrix([0.0, 1.0, 0.0], np.radians(angle))
            ratios[key].append(chamfer(a, b @ turn.T) / floor)
        ratios["mirror_x"].append(chamfer(a, b * [-1.0, 1.0, 1.0]) / floor)
        ratios["mirror_z"].append(chamfer(a, b * [1.0, 1.0, -1.0]) / floor)
    return {k: round(float(np.median(v)), 3) for k, v in ratios.items()}


def decide_symmetry(ratios: dict[str, float], threshold: float = SYMMETRY_RATIO) -> str:
    """The largest group whose turns all keep the shapes alike (ratio below ``threshold``)."""
    if ratios["yaw"] < threshold and ratios["yaw90"] < threshold:
        return "yaw"
    if ratios["yaw90"] < threshold and ratios["yaw180"] < threshold:
        return "yaw90"
    if ratios["yaw180"] < threshold:
        return "yaw180"
    return "none"


def frame_statistics(shapes: list[Shape]) -> dict[str, float]:
    """Shares of canonical shapes (M, 3) whose longest horizontal extent is along x, and whose
    upper part (top 40% of the height) sits toward +z of the lower part (40% from the bottom)."""
    along_x, leans = [], []
    for shape in shapes:
        p = shape.points
        extent = p.max(0) - p.min(0)
        along_x.append(extent[0] > extent[2])
        upper, lower = p[:, 1] > np.quantile(p[:, 1], 0.6), p[:, 1] < np.quantile(p[:, 1], 0.4)
        leans.append(p[upper, 2].mean() > p[lower, 2].mean())
    return {
        "long_axis_x": round(float(np.mean(along_x)), 2),
        "leans_+z": round(float(np.mean(leans)), 2),
    }


FRAME_COLUMNS = ("class", "ratio 90", "ratio 180", "ratio other", "measured", "declared",
                 "mirror x", "mirror z", "mirrors declared", "turn", "long axis along x",
                 "upper part toward +z")  # fmt: skip


def measured_frames(
    data: Path, names: Sequence[str], frame: str = "modelnet", shapes: int = 80
) -> list[tuple[str, ...]]:
    """Each category's measured self-match ratios, decided and declared symmetry, and how its
    shapes sit in the canonical frame after the category's turn, on ``shapes`` random training
    shapes of ``data`` (a ModelNet-style root) read in ``frame``: one row of ``FRAME_COLUMNS``
    a category."""
    from itnet.model.data import split_files
    from itnet.model.shapes import load_shape

    rng = np.random.default_rng(0)
    rows = []
    for name in names:
        cat = category(name)
        files = split_files(data, name, 0.1, 0)["train"]
        count = min(shapes, len(files))
        picked = [files[i] for i in rng.choice(len(files), count, replace=False)]
        loaded = [load_shape(f, frame, cat.quarter_turns) for f in picked]
        ratios, sits = self_match_ratios(loaded, rng), frame_statistics(loaded)
        rows.append((name, str(ratios["yaw90"]), str(ratios["yaw180"]), str(ratios["yaw"]),
                     decide_symmetry(ratios), cat.symmetry, str(ratios["mirror_x"]),
                     str(ratios["mirror_z"]), ",".join(cat.mirror_planes) or "-",
                     f"{90 * cat.quarter_turns}°", f"{sits['long_axis_x']:.0%}",
                     f"{sits['leans_+z']:.0%}"))  # fmt: skip
    return rows
