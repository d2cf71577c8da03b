"""Where the linear model stops being a deformation: det(I + grad u) per case, the tets it inverts,
the tissue under the tip.

Small strain lets u grow without limit in d while det F = det(I + grad u) is a cubic in d at every
quadrature point (linear.det_f_cubic). Past its first root some element is inside out. This module
measures, along each angle of a sweep grid: min det F, the number of inverted tets and where they
are, the exact first crossing of det F = 0 (bisection on the cubic between grid points), and the
displacement up to which every angle is valid (contracts.sweep.valid_up_to_mm). The study that
prints it is `python -m studies linear-validity` (docs/linear_validity.md).

A P2 field's det F is a polynomial over each tet, so it can turn <= 0 between the solver's 4
quadrature points while positive at them. PROBE_INTORDER names the denser rule every sweep snapshot
is also checked at (`probe`; contracts.sweep's min_det_f_probe). Points are a sample; `det_f_bound`
decides the sign of det F over every point of every tet (contracts.sweep's min_det_f_bound): on a
straight-sided tet grad u of a P2 field is affine, so det F is a cubic whose 20 Bernstein coefficients
bound it from below, tightened by subdivision where they are not all > 0.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from contracts.interpolate import PointLocator
from contracts.sweep import read_cases, valid_up_to_mm

from fem_offline.fe import elasticity as el
from fem_offline.fe.guide import direction, tip
from fem_offline.fe.linear import det_f, det_f_cubic, linear_modes, superpose
from fem_offline.fe.problem import Problem

PROBE_INTORDER = 4  # the degree-4 rule: 11 points per tet, against the solver's 4 (degree 2)


@dataclass(frozen=True)
class AngleCurve:
    """The linear model's det F along one angle of the grid."""

    angle_deg: float
    displacements_mm: np.ndarray  # (n_d,)
    min_det_f: np.ndarray  # (n_d,) over every quadrature point of the assembled tets
    n_inverted_tets: np.ndarray  # (n_d,) tets with det F <= 0 at a quadrature point
    first_inversion_mm: float | None  # where min det F first reaches 0 (to 1e-4 mm); None: not in the grid
    inverted_at_max: dict[str, int]  # tissue -> inverted tets at the largest displacement
    farthest_from_tip_mm: float  # of those tets' centroids, the largest distance from the guide tip (0: none)


def _first_root(c: np.ndarray, lo: float, hi: float, tol_mm: float = 1e-4) -> float:
    """Smallest d in (lo, hi] with min det F(d) <= 0, by bisection (min det F(lo) > 0 >= min det F(hi))."""
    def ok(d: float) -> bool:
        return (c[0] + d * (c[1] + d * (c[2] + d * c[3]))).min() > 0

    while hi - lo > tol_mm:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return hi


def resampled(problem: Problem, intorder: int | None = None, *, quadrature=None) -> Problem:
    """The problem with basis gradients at the points of another quadrature rule, or of `quadrature`
    (reference points (3, k), weights (k,)), to probe det F between the solver's own points; its weights
    W are for that rule too."""
    from skfem import Basis, ElementTetP2

    from fem_offline.geometry.mesh import skfem_mesh

    basis = Basis(skfem_mesh(problem.mesh), ElementTetP2(), intorder=intorder, quadrature=quadrature)
    G = np.stack([basis.basis[a][0].grad for a in range(10)]).transpose(2, 3, 0, 1)  # (n_tets, n_qp, 10, 3)
    active = problem.active if problem.active is not None else slice(None)
    return replace(problem, G=np.ascontiguousarray(G[active]), W=np.ascontiguousarray(basis.dx[active]))


def probe(problem: Problem) -> Problem:
    """The problem at the probe points (PROBE_INTORDER): its min_jacobian is a snapshot's min_det_f_probe."""
    return resampled(problem, PROBE_INTORDER)


def corners(problem: Problem) -> Problem:
    """The problem with basis gradients at each tet's 4 corners: its F there spans F over the tet (the
    input of det_f_bound; its W are not a quadrature)."""
    return resampled(problem, quadrature=(np.array([[0.0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), np.full(4, 1 / 24)))


# Bernstein coefficients of det(sum_i l_i F_i) over the simplex: b = D(F_i, F_j, F_k), the mixed
# determinant (det's polarisation), for each multiset {i, j, k} of corners: 4 + 12 + 4.
_MULTISETS = np.array([(i, j, k) for i in range(4) for j in range(i, 4) for k in range(j, 4)])
# Red refinement: the 4 corner tets and the octahedron cut along its 1-3 / 0-2 midpoint diagonal, as
# indices into the corners (0-3) and the edge midpoints 01, 02, 03, 12, 13, 23 (4-9).
_EDGES = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])
_CHILDREN = np.array([(0, 4, 5, 6), (1, 4, 7, 8), (2, 5, 7, 9), (3, 6, 8, 9),
                      (4, 5, 6, 8), (4, 5, 7, 8), (5, 6, 8, 9), (5, 7, 8, 9)])


def _det3(M: np.ndarray) -> np.ndarray:
    """det of stacked 3 x 3 matrices (..., 3, 3) by cofactors: 10x numpy.linalg.det's LU on 3 x 3 stacks."""
    return (M[..., 0, 0] * (M[..., 1, 1] * M[..., 2, 2] - M[..., 1, 2] * M[..., 2, 1])
            - M[..., 0, 1] * (M[..., 1, 0] * M[..., 2, 2] - M[..., 1, 2] * M[..., 2, 0])
            + M[..., 0, 2] * (M[..., 1, 0] * M[..., 2, 1] - M[..., 1, 1] * M[..., 2, 0]))


def _bernstein(F: np.ndarray) -> np.ndarray:
    """(m, 20) Bernstein coefficients of det F over simplices with affine F given at their corners (m, 4, 3, 3)."""
    a, b, c = (F[:, _MULTISETS[:, n]] for n in range(3))  # (m, 20, 3, 3)
    return (_det3(a + b + c) - _det3(a + b) - _det3(a + c) - _det3(b + c) + _det3(a) + _det3(b) + _det3(c)) / 6.0


def det_f_bound(F: np.ndarray, *, max_depth: int = 8, max_pieces: int = 2_000_000) -> float:
    """A number whose sign is that of min det F over every point of every tet, F affine over each and
    given at its corners (n_tets, 4, 3, 3) (corners(problem) and displacement_gradient).

    > 0: a lower bound of det F everywhere (the least Bernstein coefficient, after subdividing the tets
    whose coefficients were not all > 0 until they were). <= 0: det F at a corner of a piece, a point
    where the element is inside out. Pieces still undecided after `max_depth` red refinements (or past
    `max_pieces`) give their least coefficient, <= 0 (their true minimum lies between it and their corners'
    values, > 0): judged inverted, to be safe. NaN where F has a non-finite entry."""
    F = np.asarray(F, dtype=np.float64)
    if not np.isfinite(F).all():
        return float("nan")  # not a field: inverted, as contracts.sweep counts NaN
    lower = np.inf
    for depth in range(max_depth + 1):
        at_corners = _det3(F).min(initial=np.inf)
        if at_corners <= 0:
            return float(at_corners)
        coeff = _bernstein(F).min(axis=1)
        undecided = coeff <= 0
        lower = min(lower, coeff[~undecided].min(initial=np.inf))
        if not undecided.any():
            return float(lower)
        if depth == max_depth or 8 * undecided.sum() > max_pieces:
            return float(coeff[undecided].min())
        F = F[undecided]
        nodes = np.concatenate([F, 0.5 * (F[:, _EDGES[:, 0]] + F[:, _EDGES[:, 1]])], axis=1)  # (m, 10, 3, 3)
        F = nodes[:, _CHILDREN].reshape(-1, 4, 3, 3)
    raise AssertionError("unreachable")


def min_det_f_bound(at_corners: Problem, u: np.ndarray) -> float:
    """det_f_bound of displacement u (flat or (n_nodes, 3)) over the assembled tets (at_corners: corners(problem))."""
    H = el.displacement_gradient(at_corners.G, at_corners.element_displacement(np.ravel(u)))
    return det_f_bound(np.eye(3) + H)


@dataclass(frozen=True)
class DetFCheck:
    """det F between the solver's points, as every snapshot and solved case records it: at the probe
    points (a sample) and everywhere (det_f_bound)."""

    probe: Problem
    corners: Problem

    @classmethod
    def of(cls, problem: Problem) -> DetFCheck:
        return cls(probe(problem), corners(problem))

    def __call__(self, u: np.ndarray) -> dict[str, float]:
        """contracts.sweep.CaseRecord's min_det_f_probe and min_det_f_bound of displacement u."""
        u = np.ravel(u)
        return {"min_det_f_probe": self.probe.min_jacobian(u), "min_det_f_bound": min_det_f_bound(self.corners, u)}


def points_per_tet(intorder: int) -> int:
    """Quadrature points per tet of scikit-fem's degree-`intorder` rule (the problem's own: 2, 4 points)."""
    from skfem.quadrature import get_quadrature
    from skfem.refdom import RefTet

    return get_quadrature(RefTet, intorder)[0].shape[1]


def det_f_curves(problem: Problem, displacements_mm, angles_deg, *, intorder: int | None = None) -> list[AngleCurve]:
    """det F of the linear model's answer at every (d, beta) of the grid, one AngleCurve per angle.

    At the problem's quadrature points (those the solver and the sweep check), or at those of the
    degree-`intorder` rule; the model itself is always the problem's."""
    modes = linear_modes(problem)
    problem = problem if intorder is None else resampled(problem, intorder)
    mesh, d = problem.mesh, np.asarray(displacements_mm, dtype=np.float64)
    tets = np.flatnonzero(problem.active) if problem.active is not None else np.arange(len(mesh.tets))
    centroids = mesh.nodes[mesh.tets[tets, :4]].mean(axis=1)  # (n_active, 3)
    tip_mm = tip(mesh, problem.scene.guide)
    curves = []
    for angle in np.asarray(angles_deg, dtype=np.float64):
        per_tet = det_f(problem, modes, d, angle).min(axis=2)  # (n_d, n_active)
        low = per_tet.min(axis=1)
        bad = np.flatnonzero(low <= 0)
        first = None
        if bad.size:
            c = det_f_cubic(problem, modes, angle)
            lo = d[bad[0] - 1] if bad[0] > 0 else 0.0
            first = _first_root(c, lo, d[bad[0]]) if np.min(c[0]) > 0 else 0.0
        inverted = per_tet[-1] <= 0
        names, counts = np.unique(mesh.tissue[tets[inverted]], return_counts=True)
        reach = np.linalg.norm(centroids[inverted] - tip_mm, axis=1)
        curves.append(AngleCurve(float(angle), d, low, (per_tet <= 0).sum(axis=1), first,
                                 {mesh.tissue_names[t]: int(n) for t, n in zip(names, counts)},
                                 float(reach.max()) if reach.size else 0.0))
    return curves


def valid_up_to(curves: list[AngleCurve]) -> float:
    """The largest grid displacement up to which every angle's answer is valid (0: not even the first)."""
    d = curves[0].displacements_mm
    return valid_up_to_mm(d, [x for c in curves for x in c.displacements_mm[c.min_det_f <= 0]])


def tissue_along_axis(problem: Problem, *, length_mm: float = 25.0,
                      step_mm: float = 0.05) -> list[tuple[str, float, float]]:
    """(tissue, from mm, to mm) runs along the guide's push axis (beta = 0) from the tip into the body."""
    mesh = problem.mesh
    s = np.arange(0.0, length_mm + step_mm / 2, step_mm)
    points = tip(mesh, problem.scene.guide) + s[:, None] * direction(problem.scene.guide, 0.0)
    tet, _ = PointLocator(mesh.nodes, mesh.tets).locate(points)
    names = np.array([mesh.tissue_names[mesh.tissue[t]] if t >= 0 else "outside" for t in tet])
    starts = np.r_[0, np.flatnonzero(names[1:] != names[:-1]) + 1]
    edges = np.r_[s[starts], s[-1]]  # a run ends where the next tissue's first sample is
    return [(str(names[a]), float(lo), float(hi)) for a, lo, hi in zip(starts, edges[:-1], edges[1:])]


def recorded_min_det_f(manifest) -> np.ndarray:
    """(n_angles, n_displacements) min det F a sweep's snapshots record (contracts.sweep manifest);
    NaN where missing."""
    grid = manifest.grid
    table = np.full((len(grid.angles_deg), len(grid.displacements_mm)), np.nan)
    for r in manifest.snapshots:
        table[grid.angles_deg.index(r.angle_deg), grid.displacements_mm.index(r.displacement_mm)] = r.min_det_f
    return table


def linear_bound_table(problem: Problem, displacements_mm, angles_deg) -> np.ndarray:
    """(n_angles, n_displacements) min_det_f_bound of the linear model's answer at every (d, beta) of a grid."""
    modes, at_corners = linear_modes(problem), corners(problem)
    return np.array([[min_det_f_bound(at_corners, superpose(modes, d, a)) for d in displacements_mm]
                     for a in angles_deg])


def snapshot_table(folder: Path, manifest, measure) -> np.ndarray:
    """(n_angles, n_displacements) measure(u) of a sweep's snapshot files (u flat), one angle's fields at a time; NaN
    where missing."""
    grid = manifest.grid
    table = np.full((len(grid.angles_deg), len(grid.displacements_mm)), np.nan)
    for i, angle in enumerate(grid.angles_deg):
        rows = [r for r in manifest.snapshots if r.angle_deg == angle]
        if rows:
            _, fields = read_cases([Path(folder) / r.file for r in rows])
            for r, u in zip(rows, fields):
                table[i, grid.displacements_mm.index(r.displacement_mm)] = measure(u.ravel())
    return table


def probed_min_det_f(problem: Problem, folder: Path, manifest, *, intorder: int) -> np.ndarray:
    """Like recorded_min_det_f, but measured on the snapshot files at the points of the degree-`intorder` rule."""
    return snapshot_table(folder, manifest, resampled(problem, intorder).min_jacobian)


def bounded_min_det_f(problem: Problem, folder: Path, manifest) -> np.ndarray:
    """Like recorded_min_det_f, but min_det_f_bound (everywhere in every tet) measured on the snapshot files."""
    at_corners = corners(problem)
    return snapshot_table(folder, manifest, lambda u: min_det_f_bound(at_corners, u))


def table_validity(displacements_mm, table: np.ndarray) -> tuple[float, list[float | None]]:
    """(valid up to mm, first inverted grid displacement per angle or None) of a (n_angles, n_d) min det F table."""
    d = np.asarray(displacements_mm, dtype=np.float64)
    bad = ~(table > 0) & np.isfinite(table)
    first = [float(d[row].min()) if row.any() else None for row in bad]
    return valid_up_to_mm(d.tolist(), [x for x in first if x is not None]), first
