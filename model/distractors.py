"""Things in a room that are none of the categories: ottomans, boxes, bins, floor lamps, plants.

A room's floor holds more than furniture of the ten categories, and a scene's segmentation finds
those things too. ``distractor`` makes one such thing at a real size, as a ``Shape`` (points on
its surface, unit bounding radius about its box's centre, +y up) and its size in metres, so the
development scenes render it as they render their objects (``model.scenes``):

* ``ottoman``: a padded box, 0.4-1.2 m wide, 0.35-0.5 m tall (a storage box or pouffe alike);
* ``bin``: an open cylinder, 0.2-0.45 m across, 0.3-0.75 m tall (a bin, a basket, a stool);
* ``lamp``: a floor lamp, a disc base, a pole 1.2-1.7 m and a shade (a truncated cone);
* ``plant``: a pot and foliage above it, a cloud of leaves 0.3-0.8 m across;
* ``cabinet``: a tall narrow case 0.3-0.6 m wide, 1.2-2.0 m tall (a wardrobe's side, a
  bookcase seen from the side), taller than any night stand or dresser.

Things hung on a room's wall (``hung``, ``HUNG_KINDS``) are none of them either: they stand
out of the wall by a few centimetres and run along it, past the furniture standing against it:

* ``picture``: a frame 0.3-1.0 m wide, 0.3-0.9 m tall, 2-5 cm deep;
* ``mirror``: 0.5-1.2 m wide, 0.6-1.2 m tall, 2-6 cm deep (a dresser's mirror hung above it);
* ``skirting``: a board along the floor, 7-15 cm tall, 1-2.5 cm deep, as long as the wall seen.

Sizes are those of common retail pieces (IKEA's ottomans, bins, floor lamps, bookcases, frames
and mirrors). Pure numpy.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from itnet.model.shapes import Shape

KINDS = ("ottoman", "bin", "lamp", "plant", "cabinet")
HUNG_KINDS = ("picture", "mirror", "skirting")
POINTS = 1536  # surface points a distractor's shape holds


def distractor(kind: str, rng: np.random.Generator) -> tuple[Shape, float]:
    """A thing of ``kind`` (``KINDS``) at a random real size -> (its Shape: unit bounding radius
    about its box's centre, standing on +y; metres per unit of it)."""
    makers = {"ottoman": _ottoman, "bin": _bin, "lamp": _lamp, "plant": _plant,
              "cabinet": _cabinet}  # fmt: skip
    if kind not in makers:
        raise ValueError(f"unknown distractor {kind!r} (known: {', '.join(KINDS)})")
    points = makers[kind](rng)  # metres, standing on y = 0
    return _unit_shape(kind, points - (points.min(0) + points.max(0)) / 2)


def hung(kind: str, rng: np.random.Generator, length_m: float = 6.0) -> tuple[Shape, float]:
    """A thing of ``kind`` (``HUNG_KINDS``) hung on a wall -> (its Shape: unit bounding radius
    about its box's centre, x along the wall, y up, z out of the wall; metres per unit of it);
    ``length_m``: a skirting board's length."""
    sizes = {
        "picture": lambda: (rng.uniform(0.3, 1.0), rng.uniform(0.3, 0.9), rng.uniform(0.02, 0.05)),
        "mirror": lambda: (rng.uniform(0.5, 1.2), rng.uniform(0.6, 1.2), rng.uniform(0.02, 0.06)),
        "skirting": lambda: (length_m, rng.uniform(0.07, 0.15), rng.uniform(0.01, 0.025)),
    }
    if kind not in sizes:
        raise ValueError(f"unknown hung thing {kind!r} (known: {', '.join(HUNG_KINDS)})")
    points = box_surface(np.array(sizes[kind]()), POINTS, rng)
    points[:, 1] -= points[:, 1].max() / 2  # about its box's centre
    return _unit_shape(kind, points)


def _unit_shape(kind: str, points: NDArray) -> tuple[Shape, float]:
    """Points (M, 3) in metres about a thing's centre -> (its Shape of unit bounding radius,
    metres per unit)."""
    radius = float(np.linalg.norm(points, axis=1).max())
    return Shape(kind, points / radius), radius


def box_surface(size: NDArray, count: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """Points on a box's faces (``size`` (3,), standing on y = 0, centred in x and z), each face
    in proportion to its area."""
    w, h, d = size
    areas = np.array([h * d, h * d, w * d, w * d, w * h, w * h])
    face = rng.choice(6, size=count, p=areas / areas.sum())
    p = rng.uniform(-0.5, 0.5, (count, 3)) * size
    axis = face // 2
    p[np.arange(count), axis] = np.where(face % 2, 0.5, -0.5) * size[axis]
    p[:, 1] += h / 2
    return p


def _cylinder_surface(
    radius: float, height: float, count: int, rng: np.random.Generator, top: bool = True
) -> NDArray[np.float64]:
    """Points on a cylinder's side (and top) standing on y = 0."""
    side, cap = 2 * math.pi * radius * height, math.pi * radius**2 if top else 0.0
    on_top = rng.random(count) < cap / (side + cap)
    angle = rng.uniform(0, 2 * math.pi, count)
    r = np.where(on_top, radius * np.sqrt(rng.random(count)), radius)
    y = np.where(on_top, height, rng.uniform(0, height, count))
    return np.stack([r * np.cos(angle), y, r * np.sin(angle)], 1)


def _ottoman(rng: np.random.Generator) -> NDArray[np.float64]:
    width = rng.uniform(0.4, 1.2)
    size = np.array([width, rng.uniform(0.35, 0.5), width * rng.uniform(0.5, 1.0)])
    return box_surface(size, POINTS, rng)


def _bin(rng: np.random.Generator) -> NDArray[np.float64]:
    return _cylinder_surface(rng.uniform(0.1, 0.225), rng.uniform(0.3, 0.75), POINTS, rng,
                             top=rng.random() < 0.5)  # fmt: skip


def _lamp(rng: np.random.Generator) -> NDArray[np.float64]:
    pole = rng.uniform(1.2, 1.7)
    base = _cylinder_surface(rng.uniform(0.12, 0.2), 0.03, POINTS // 6, rng)
    stick = _cylinder_surface(0.012, pole, POINTS // 6, rng, top=False)
    low, high, tall = rng.uniform(0.18, 0.28), rng.uniform(0.1, 0.18), rng.uniform(0.2, 0.35)
    k = POINTS - len(base) - len(stick)
    t = rng.random(k)
    angle = rng.uniform(0, 2 * math.pi, k)
    r = low + (high - low) * t
    shade = np.stack([r * np.cos(angle), pole - 0.1 + tall * t, r * np.sin(angle)], 1)
    return np.concatenate([base, stick, shade])


def _plant(rng: np.random.Generator) -> NDArray[np.float64]:
    pot_r, pot_h = rng.uniform(0.1, 0.2), rng.uniform(0.2, 0.4)
    pot = _cylinder_surface(pot_r, pot_h, POINTS // 4, rng)
    spread = rng.uniform(0.15, 0.4)
    k = POINTS - len(pot)
    blobs = rng.normal(size=(6, 3)) * spread * 0.5
    blobs[:, 1] = np.abs(blobs[:, 1]) + pot_h + spread
    leaf = blobs[rng.integers(6, size=k)] + rng.normal(size=(k, 3)) * spread * 0.35
    leaf[:, 1] = np.maximum(leaf[:, 1], pot_h)
    return np.concatenate([pot, leaf])


def _cabinet(rng: np.random.Generator) -> NDArray[np.float64]:
    size = np.array([rng.uniform(0.3, 0.6), rng.uniform(1.2, 2.0), rng.uniform(0.3, 0.6)])
    return box_surface(size, POINTS, rng)
