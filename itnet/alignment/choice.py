"""How likely each candidate alignment is right: its evidence, a calibrated model, the choice.

Pure numpy. A candidate T_b_from_a is judged by what can be measured without the truth:

* ``fitness``: the symmetric share of points of the two clouds within the inlier distance once A
  is moved (after ICP where it was refined): how well the clouds agree where they overlap;
* ``loose``: the same share at the ranking distance (0.2 radii): how much they overlap at all. A
  pair that overlaps little says little by its fitness, and the model learns to trust it less;
* ``support``: the share of the two clouds' IT-Net run pairs (A's run i, B's run j, no turn)
  whose composed pose lies within 15 degrees and 0.15 radii of the candidate (before ICP): the
  networks' own agreement on it, which is each pose's confidence;
* ``served``, ``turned``, ``refined``: whether it is built from the two served poses, whether
  a symmetry turn was applied, whether ICP moved it; ``move``: how far ICP moved it (tens of
  degrees plus radii): a long slide is often ICP leaving a right pose for a wrong one;
* ``gain``: its fitness minus the best fitness of the composed poses (with and without ICP):
  a rival must explain the geometry better than the prior to be believed.

``probability`` maps these through a logistic model fitted on validation pairs of every pair
generator and several categories (``CALIBRATION``, ``python -m benchmarks.align_calibrate``),
so that of the alignments it calls 90% sure about 90% are right
(docs/align.md). ``choose`` keeps the composed poses unless a rival is more likely right.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from itnet.geometry import rotation_error_deg

FEATURES = ("bias", "fitness", "loose", "support", "served", "turned", "refined", "move", "gain")
CALIBRATION = Path(__file__).with_name("calibration.json")
SUPPORT_DEG = 15.0  # a run pair backs a candidate within this rotation ...
SUPPORT_SHIFT = 0.15  # ... and this many radii of translation


@dataclass(frozen=True)
class Calibration:
    """Logistic weights, one per name of ``FEATURES``, and what they were fitted on."""

    weights: NDArray[np.float64]
    fitted_on: str = ""

    @classmethod
    def read(cls, path: Path = CALIBRATION) -> Calibration:
        data = json.loads(path.read_text())
        if tuple(data["features"]) != FEATURES:
            raise ValueError(f"{path}: features {data['features']} are not {list(FEATURES)}")
        return cls(np.asarray(data["weights"], dtype=np.float64), str(data.get("fitted_on", "")))

    def write(self, path: Path, **about: object) -> None:
        data = {"features": list(FEATURES), "weights": [round(float(w), 6) for w in self.weights],
                "fitted_on": self.fitted_on, **about}  # fmt: skip
        path.write_text(json.dumps(data, indent=1) + "\n")


@cache
def shipped() -> Calibration:
    """The calibration that ships beside this module."""
    return Calibration.read()


def support(candidates: ArrayLike, run_pairs: ArrayLike, scale: float) -> NDArray[np.float64]:
    """Candidates T_b_from_a (H, 4, 4), the run pairs' composed poses (P, 4, 4) -> the share of
    run pairs within SUPPORT_DEG and SUPPORT_SHIFT x scale of each candidate (H,)."""
    h = np.asarray(candidates, dtype=np.float64).reshape(-1, 4, 4)
    p = np.asarray(run_pairs, dtype=np.float64).reshape(-1, 4, 4)
    close = rotation_error_deg(h[:, None, :3, :3], p[None, :, :3, :3]) < SUPPORT_DEG
    close &= np.linalg.norm(h[:, None, :3, 3] - p[None, :, :3, 3], axis=-1) < SUPPORT_SHIFT * scale
    return close.mean(axis=1)


def icp_move(initial: ArrayLike, refined: ArrayLike, scale: float) -> float:
    """How far ICP moved a candidate (4x4 each): degrees / 10 plus the translation in radii."""
    a, b = np.asarray(initial, np.float64), np.asarray(refined, np.float64)
    degrees = float(rotation_error_deg(a[:3, :3], b[:3, :3]))
    return degrees / 10.0 + float(np.linalg.norm(a[:3, 3] - b[:3, 3])) / scale


def feature_row(fitness: float, loose: float, backing: float, served: bool, turned: bool,
                move: float | None, gain: float) -> NDArray[np.float64]:  # fmt: skip
    """One candidate's evidence in ``FEATURES`` order (``move`` None: not refined)."""
    refined = move is not None
    return np.array([1.0, fitness, loose, backing, float(served), float(turned), float(refined),
                     move or 0.0, gain])  # fmt: skip


def probability(rows: ArrayLike, calibration: Calibration | None = None) -> NDArray[np.float64]:
    """Evidence (H, len(FEATURES)) -> the calibrated probability that each is right (H,)."""
    weights = (calibration or shipped()).weights
    logits = np.asarray(rows, dtype=np.float64).reshape(-1, len(FEATURES)) @ weights
    return 1.0 / (1.0 + np.exp(-np.clip(logits, -40.0, 40.0)))


def choose(probabilities: ArrayLike) -> int:
    """The candidate to report: the likeliest; the first (the composed poses) on a tie."""
    p = np.asarray(probabilities, dtype=np.float64)
    return int(np.argmax(p)) if len(p) else 0


def fit_logistic(rows: ArrayLike, labels: ArrayLike, l2: float = 1e-2,
                 steps: int = 50) -> NDArray[np.float64]:  # fmt: skip
    """Logistic regression by Newton's method: evidence (K, F), right or not (K,) -> weights
    (F,); ``l2`` keeps the weights of rare features finite (the bias is not penalised)."""
    x = np.asarray(rows, dtype=np.float64)
    y = np.asarray(labels, dtype=np.float64)
    w = np.zeros(x.shape[1])
    penalty = np.full(x.shape[1], l2)
    penalty[0] = 0.0
    for _ in range(steps):
        p = 1.0 / (1.0 + np.exp(-np.clip(x @ w, -40, 40)))
        gradient = x.T @ (p - y) + penalty * w
        hessian = (x * (p * (1 - p))[:, None]).T @ x + np.diag(penalty + 1e-9)
        step = np.linalg.solve(hessian, gradient)
        w -= step
        if np.abs(step).max() < 1e-8:
            break
    return w
