"""Frictionless contact of the rigid guide tip with the rectal wall (effects.guide_contact).

The guide's rounded end is a rigid sphere of radius R = guide.tip_radius_mm. At rest it touches the
wall at the tip point: centre c_0 = tip - R n, n = guide.axis (the wall's inward normal there). A
guide displacement d moves it along its tilted axis, c(d, beta) = c_0 + d a(beta). The wall slides
along it freely (no friction) but does not pass into it.

A point of the lumen surface at its current position x = X + u has the gap g = |x - c| - R and the
penetration p = -g - o. The faceted lumen lies inside the round one (a chord's sag, 0.06 mm on the
tiny phantom's 2.5 mm faces), so at rest some points would already lie inside the sphere; like a
strain-free adjustment of initial overclosure, o_q = max(R - |X_q - c_0|, 0) is removed from each
point's penetration, so that the rest state is exactly free of contact (o -> 0 as h^2). Augmented Lagrangian at the
quadrature points q of the lumen faces (scikit-fem FacetBasis on the reference surface, area weights w_q):

    Pi_c(u)   = sum_q w_q (<lam_q + k p_q>^2 - lam_q^2) / (2 k)
    pressure  t_q = <lam_q + k p_q>  (kPa, per reference area),  n_q = (x_q - c) / |x_q - c|
    residual  r_a = dPi_c/du_a = -sum_q w_q t_q N_a(q) n_q
    Hessian   K_ab = sum_q w_q N_a N_b [k n n^T [t_q > 0] - t_q (I - n n^T) / |x_q - c|]

The last term is the sphere's curvature; it is negative. From the first iterations of a step, where
the penetrations (and so the pressures) are still far from equilibrium, it made the tangent lose
definiteness (PARDISO's SPD factorisation failed): 155 factorisations on the tiny phantom's 10 mm
path at k = 1e5 instead of 73 (same answer). Without it Newton converges linearly at the end, halving
the residual each iteration. So Newton adds it once the relative residual is below 1e-2
(newton.EXACT_CONTACT_BELOW), where the tangent is the exact Hessian of a stable equilibrium. With
that and the merged multiplier update below, the default mesh's 10 mm path at beta = 10 deg (0.25 mm
steps) took 206 Newton iterations instead of 459, 1,689 CG iterations instead of 3,478, 62
factorisations instead of 74 and no extra multiplier update instead of 11 (`python -m studies profile-path`
on the default sweep's mesh); the fields agree within the contact tolerance.
Between Newton
solves at one guide position the multipliers are updated, lam <- t (Uzawa, continuation.py), until
the deepest penetration is below guide.contact_tol_mm; the next step starts from the last
equilibrium's pressures. The penalty
k = guide.contact_stiffness_kpa_mm (or contact_stiffness_per_mm x the stiffest deforming tissue's E, so that it
scales with the tissues) sets how fast that converges, not the answer. Tiny phantom,
10 mm at beta = 10 deg, 0.5 mm steps: k = 1e4 needs 23 updates (98 s), 3e4 one (70 s), 1e5 none
but 73 factorisations (85 s), 1e6 none (205 s); the fields agree to 0.014 mm. Default 3e4.
Lengths in mm, pressures in kPa, energies in mJ (kPa mm^3).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from contracts.tet10 import boundary_faces

from fem_offline.fe import guide as guide_mod

if TYPE_CHECKING:
    from fem_offline.geometry.mesh import TetMesh
    from fem_offline.scene import Guide

FACE_INTORDER = 4  # 6 points per face: the gap is quadratic on a P2 face until the contact rim


@dataclass(frozen=True)
class Surface:
    """The lumen faces that can touch the tip, at their quadrature points."""

    tet: np.ndarray  # (f,) each face's tet, as a row of the assembled (active) tets
    edofs: np.ndarray  # (f, 30) global DOFs of that tet
    N: np.ndarray  # (f, q, 10) P2 shape values of the tet's nodes at the face's quadrature points
    X: np.ndarray  # (f, q, 3) reference positions of the quadrature points
    w: np.ndarray  # (f, q) reference area weights
    rest_centre: np.ndarray  # (3,) c_0
    radius_mm: float
    stiffness: float  # k, kPa/mm
    tol_mm: float
    overclosure: np.ndarray  # (f, q) o_q = max(R - |X_q - c_0|, 0), removed from the penetration

    @property
    def shape(self) -> tuple[int, int]:
        return self.w.shape


class Load(NamedTuple):
    """Where the tip is and the multipliers carried from the last update."""

    centre: np.ndarray  # (3,)
    multipliers: np.ndarray  # (f, q) kPa


class State(NamedTuple):
    """Contact at one displacement field."""

    energy: float
    force: np.ndarray  # (f, 10, 3) the residual's share per face
    pressure: np.ndarray  # (f, q) t
    penetration: np.ndarray  # (f, q) p = R - |x - c| - o
    normal: np.ndarray  # (f, q, 3)
    distance: np.ndarray  # (f, q) |x - c|


def lumen_faces(mesh: TetMesh) -> np.ndarray:
    """Boundary faces owned by the rectal wall (the lumen is a hole in it): (k, 6) nodes, corners first."""
    if "rectal_wall" not in mesh.tissue_names:
        raise ValueError("effects.guide_contact: the mesh has no rectal_wall tissue for the guide to touch")
    ext, owner = boundary_faces(mesh.tets)
    return ext[mesh.tissue[owner] == mesh.tissue_names.index("rectal_wall")]


def rest_centre(mesh: TetMesh, guide: Guide) -> np.ndarray:
    """c_0 = tip - R n: the sphere touching the wall at the tip, n = guide.axis normalised."""
    n = np.asarray(guide.axis, dtype=np.float64)
    return guide_mod.tip(mesh, guide) - guide.tip_radius_mm * n / np.linalg.norm(n)


def centre(surface: Surface, guide: Guide, displacement_mm: float, angle_deg: float) -> np.ndarray:
    """c(d, beta) = c_0 + d a(beta)."""
    return surface.rest_centre + displacement_mm * guide_mod.direction(guide, angle_deg)


def penalty(guide: Guide, stiffest_youngs_kpa: float) -> float:
    """The penalty k (kPa/mm): guide.contact_stiffness_per_mm x the stiffest deforming tissue's E when set, else
    contact_stiffness_kpa_mm.

    Why the stiffest and not the wall the tip touches: the pressure under the tip is what the whole stack behind the
    wall resists, and the updates converge at a rate set by k against that stiffness (module docstring). A wall 10x
    softer than the gland behind it made k 10x softer with it, and the updates stopped converging before the largest
    push (docs/hard_cases.md). Any E that scales with every tissue keeps k x s for E x s, so u still moves with the
    ratios only."""
    if guide.contact_stiffness_per_mm is None:
        return guide.contact_stiffness_kpa_mm
    return guide.contact_stiffness_per_mm * stiffest_youngs_kpa


def build_surface(mesh: TetMesh, skfem_mesh, tets: np.ndarray, active: np.ndarray, guide: Guide,
                  stiffest_youngs_kpa: float) -> Surface:
    """The lumen faces within reach of the tip (2 R + 30 mm of c_0: d_max <= 30 mm, scene.Sweep).

    tets: (n_tets, 10) element nodes in scikit-fem's local order; active: (n_tets,) bool, the
    assembled tets; stiffest_youngs_kpa: the stiffest deforming tissue's E, which a scaled penalty follows (`penalty`).
    """
    corners = np.sort(lumen_faces(mesh)[:, :3], axis=1)
    if corners.size == 0:
        raise ValueError("effects.guide_contact: the rectal wall has no lumen surface")
    facets = np.sort(skfem_mesh.facets.T, axis=1)
    boundary = skfem_mesh.boundary_facets()
    lookup = {tuple(f): i for i, f in zip(boundary, facets[boundary])}
    ids = np.array([lookup[tuple(f)] for f in corners])
    c0 = rest_centre(mesh, guide)
    reach = 2 * guide.tip_radius_mm + 30.0
    near = (np.linalg.norm(skfem_mesh.p[:, skfem_mesh.facets[:, ids]].T - c0, axis=2) < reach).any(axis=1)
    return facet_surface(skfem_mesh, ids[near], tets, active, rest_centre=c0, radius_mm=guide.tip_radius_mm,
                         stiffness=penalty(guide, stiffest_youngs_kpa), tol_mm=guide.contact_tol_mm)


def facet_surface(skfem_mesh, facets: np.ndarray, tets: np.ndarray, active: np.ndarray, *, rest_centre: np.ndarray,
                  radius_mm: float, stiffness: float, tol_mm: float) -> Surface:
    """Contact data on the given boundary facets of a scikit-fem mesh (P2 facet quadrature)."""
    from skfem import ElementTetP2, FacetBasis

    fb = FacetBasis(skfem_mesh, ElementTetP2(), facets=facets, intorder=FACE_INTORDER)
    if not active[fb.tind].all():
        raise ValueError("effects.guide_contact: a contact face lies on a tet whose nodes are all fixed")
    X = np.asarray(fb.global_coordinates().value).transpose(1, 2, 0)  # (f, q, 3)
    N = np.stack([fb.basis[a][0].value for a in range(10)], axis=-1)  # (f, q, 10)
    edofs = (3 * tets[fb.tind][:, :, None] + np.arange(3)).reshape(len(fb.tind), 30)
    row = np.cumsum(active) - 1
    c0 = np.asarray(rest_centre, dtype=np.float64)
    overclosure = np.maximum(radius_mm - np.linalg.norm(X - c0, axis=2), 0.0)
    return Surface(row[fb.tind], edofs, np.ascontiguousarray(N), np.ascontiguousarray(X), np.ascontiguousarray(fb.dx),
                   c0, radius_mm, stiffness, tol_mm, overclosure)


def evaluate(s: Surface, u: np.ndarray, load: Load) -> State:
    """Energy, residual share and pressures of the contact at u (n_dofs,)."""
    ue = u[s.edofs].reshape(-1, 10, 3)
    x = s.X + np.einsum("fqa,fai->fqi", s.N, ue)
    v = x - load.centre
    dist = np.linalg.norm(v, axis=2)
    n = v / np.maximum(dist, 1e-300)[..., None]
    p = s.radius_mm - dist - s.overclosure
    t = np.maximum(load.multipliers + s.stiffness * p, 0.0)
    energy = float(np.sum(s.w * (t**2 - load.multipliers**2)) / (2 * s.stiffness))
    force = -np.einsum("fq,fqa,fqi->fai", s.w * t, s.N, n)
    return State(energy, force, t, p, n, dist)


def stiffness(s: Surface, st: State, curvature: bool = False) -> np.ndarray:
    """The contact tangent per face (f, 10, 3, 10, 3); with `curvature`, the exact Hessian of Pi_c.

    Newton adds the curvature term only near convergence (see the module docstring)."""
    on = st.pressure > 0
    nn = st.normal[..., :, None] * st.normal[..., None, :]  # (f, q, 3, 3)
    A = s.stiffness * on[..., None, None] * nn  # (f, q, 3, 3)
    if curvature:
        A = A - (st.pressure / st.distance)[..., None, None] * (np.eye(3) - nn)
    A = s.w[..., None, None] * A
    return np.einsum("fqa,fqb,fqik->faibk", s.N, s.N, A, optimize=True)


def scatter(s: Surface, force: np.ndarray, n_dofs: int) -> np.ndarray:
    """Global vector (n_dofs,) from per-face vectors (f, 10, 3)."""
    return np.bincount(s.edofs.ravel(), weights=force.ravel(), minlength=n_dofs)


def add_stiffness(s: Surface, Ke: np.ndarray, st: State, curvature: bool = False) -> None:
    """Ke (n_active, 10, 3, 10, 3) += the contact tangent of each face's tet, in place."""
    np.add.at(Ke, s.tet, stiffness(s, st, curvature))


def resultant(s: Surface, st: State) -> np.ndarray:
    """The force the wall exerts on the tip (3,), mN: sum_q w t n pushes the tip back along -n."""
    return -np.einsum("fq,fqi->i", s.w * st.pressure, st.normal)
