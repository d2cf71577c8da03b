"""Aim the needle: the guide pose whose needle path passes closest to a lesion once the tissue has moved.

The needle leaves the guide's tip along the guide's axis. After the push (d, beta) the tip is at
T + d a(beta) and the axis is a(beta) (service/guide.py), so the needle path is the ray

    N(s) = T + (d + s) a(beta),  s >= 0

and the lesion, at X in the reference state, is at L(d, beta) = X + u_X(d, beta) (the surrogate). The plan is

    (d, beta)^ = argmin over the envelope of miss(d, beta) = min over s >= 0 of |L(d, beta) - N(s)|

(d held at the clinician's value when given), found on a (d, beta) grid refined around its best cell. Naive
aiming points the ray at the undisplaced X (the beta whose ray passes closest to X) and pushes the same d.
A material model's stiffnesses come with their std: the miss's std is the std of L across the ray (first order
through du/d ln E, the graph's own sensitivities).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..guide import Guide
from ..model import Predictor
from .fit import PointSet, StateSpace, positions, with_jacobian

REACH_MM = 2.5  # the clinical target: a biopsy needle within 2.5 mm of the lesion (Karnik et al., via the paper)
GRID = (21, 41)  # the first (d, beta) grid: 0.5 mm and 0.5 deg on the default envelope
REFINE = 4  # times the grid is refined around its best cell (each 11 x 11, a fifth of the cell)


@dataclass(frozen=True)
class Aim:
    """One pose and where its needle path passes the lesion."""

    displacement_mm: float
    angle_deg: float
    lesion_mm: np.ndarray  # (3,) the displaced lesion at this pose
    miss_mm: float  # distance from the lesion to the needle ray
    depth_mm: float  # s: how far past the pushed tip the ray passes closest to the lesion


@dataclass(frozen=True)
class Plan:
    best: Aim
    miss_std_mm: float  # from the stiffnesses' std (0 without material inputs)
    naive: Aim  # aiming at the undisplaced lesion with the same push

    @property
    def reachable(self) -> bool:
        return self.best.miss_mm <= REACH_MM


def ray_miss(guide: Guide, displacement_mm: np.ndarray, angle_deg: np.ndarray,
             lesion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(miss mm, depth s mm) of each pose's needle ray from the lesion positions (b, 3)."""
    b = np.deg2rad(np.asarray(angle_deg, dtype=np.float64))[:, None]
    a = guide.axis * np.cos(b) + np.cross(guide.tilt_normal, guide.axis) * np.sin(b)  # (b, 3) a(beta), contracts.guide
    start = guide.tip_mm + np.asarray(displacement_mm, dtype=np.float64)[:, None] * a
    v = lesion - start
    s = np.maximum((v * a).sum(axis=1), 0.0)
    return np.linalg.norm(v - s[:, None] * a, axis=1), s


def _poses(space: StateSpace, theta: np.ndarray, d: np.ndarray, b: np.ndarray) -> np.ndarray:
    dd, bb = np.meshgrid(d, b, indexing="ij")
    return np.column_stack([dd.ravel(), bb.ravel(), np.tile(theta, (dd.size, 1))])


def _best(predictor: Predictor, space: StateSpace, guide: Guide, lesion: PointSet, states: np.ndarray) -> Aim:
    at = positions(predictor, space, lesion, states)[:, 0]  # (b, 3)
    miss, depth = ray_miss(guide, states[:, 0], states[:, 1], at)
    i = int(np.argmin(miss))
    return Aim(float(states[i, 0]), float(states[i, 1]), at[i], float(miss[i]), float(depth[i]))


def plan(predictor: Predictor, space: StateSpace, guide: Guide, lesion: PointSet, *, theta: np.ndarray,
         theta_std: np.ndarray, displacement_mm: float | None = None) -> Plan:
    """The pose in the envelope (or at the given d) whose needle ray passes closest to the displaced lesion."""
    lo, hi = space.lower[:2], space.upper[:2]
    d = np.array([displacement_mm]) if displacement_mm is not None else np.linspace(lo[0], hi[0], GRID[0])
    b = np.linspace(lo[1], hi[1], GRID[1])
    best = _best(predictor, space, guide, lesion, _poses(space, theta, d, b))
    cell = np.array([(hi[0] - lo[0]) / (GRID[0] - 1), (hi[1] - lo[1]) / (GRID[1] - 1)])
    for _ in range(REFINE):
        if displacement_mm is None:
            d = np.clip(np.linspace(best.displacement_mm - cell[0], best.displacement_mm + cell[0], 11), lo[0], hi[0])
        b = np.clip(np.linspace(best.angle_deg - cell[1], best.angle_deg + cell[1], 11), lo[1], hi[1])
        best = min(best, _best(predictor, space, guide, lesion, _poses(space, theta, d, b)), key=lambda a: a.miss_mm)
        cell = cell / 5
    return Plan(best, _miss_std(predictor, space, guide, lesion, best, theta, theta_std),
                naive(predictor, space, guide, lesion, theta=theta, displacement_mm=best.displacement_mm))


def naive(predictor: Predictor, space: StateSpace, guide: Guide, lesion: PointSet, *, theta: np.ndarray,
          displacement_mm: float) -> Aim:
    """Aim at the undisplaced lesion (the beta whose ray passes closest to it), push d, and see what it misses."""
    b = np.linspace(space.lower[1], space.upper[1], 2001)
    miss, _ = ray_miss(guide, np.full(len(b), displacement_mm), b, np.tile(lesion.reference[0], (len(b), 1)))
    state = np.concatenate([[displacement_mm, b[int(np.argmin(miss))]], theta])
    return _best(predictor, space, guide, lesion, state[None])


def _miss_std(predictor, space, guide, lesion, best: Aim, theta, theta_std) -> float:
    """The std of the lesion's position across the ray (along the miss, or its largest direction at a hit)."""
    if space.n_materials == 0:
        return 0.0
    _, jac = with_jacobian(predictor, space, lesion, np.concatenate([[best.displacement_mm, best.angle_deg], theta]))
    j = jac[0][:, 2:]  # (3, m) dL / d theta
    cov = j @ np.diag(np.asarray(theta_std) ** 2) @ j.T
    a = guide.direction(best.angle_deg)
    across = np.eye(3) - np.outer(a, a)
    cov = across @ cov @ across
    off = best.lesion_mm - (guide.tip_mm + (best.displacement_mm + best.depth_mm) * a)
    if best.miss_mm > 1e-6:
        n = off / np.linalg.norm(off)
        return float(np.sqrt(max(n @ cov @ n, 0.0)))
    return float(np.sqrt(max(np.linalg.eigvalsh(cov)[-1], 0.0)))
