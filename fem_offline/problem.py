"""The discrete problem: P2 basis data, materials, constraints and loads for the effects a scene switches on.

Boundary conditions (u in mm):
    bones (effects.fixed_bones):  u = 0 on every node of a bone tissue
    table (effects.table):        u_z = 0 on the bottom face z = z_min (frictionless sliding)
    guide:                        u = d w(X) a(beta) on the wall patch, w = cos^2(pi r / 2R)
    gravity (effects.gravity):    body force -rho g e_z, rho g in kPa/mm
Tets whose nodes are all fixed (the bones) cannot change K_II and are not assembled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import elasticity as el
from .assembly import Pattern, assemble_vector, build_pattern
from .mesh import TetMesh, skfem_mesh
from .regions import guide_weights
from .scene import Scene

G_MM_S2 = 9.81
PA_TO_KPA_PER_MM = 1e-6  # rho [kg/m^3] * g [m/s^2] = N/m^3 = 1e-6 kPa/mm


@dataclass(frozen=True)
class Problem:
    scene: Scene
    mesh: TetMesh
    G: np.ndarray  # (n_active, n_qp, 10, 3)
    W: np.ndarray  # (n_active, n_qp)
    mu: np.ndarray  # (n_active,) kPa
    lam: np.ndarray  # (n_active,) kPa
    pattern: Pattern
    fixed_dofs: np.ndarray  # held at zero
    guide_dofs: np.ndarray  # (n_patch, 3)
    guide_weight: np.ndarray  # (n_patch,)
    body_force: np.ndarray | None  # (n_dofs,) or None when gravity is off
    active: np.ndarray | None = None  # (n_tets,) bool: the tets assembled (not all-constrained)

    @property
    def n_dofs(self) -> int:
        return self.pattern.n_dofs

    @property
    def free(self) -> np.ndarray:
        return self.pattern.free

    @property
    def nonlinear(self) -> bool:
        return self.scene.effects.geometric_nonlinearity

    def dirichlet(self, displacement_mm: float, angle_deg: float) -> np.ndarray:
        """Prescribed displacement on all DOFs (zero where free)."""
        g = np.zeros(self.n_dofs)
        g[self.guide_dofs] = displacement_mm * self.guide_weight[:, None] * self.scene.guide.direction(angle_deg)
        return g

    def element_displacement(self, u: np.ndarray) -> np.ndarray:
        return u[self.pattern.edofs].reshape(-1, 10, 3)

    def min_jacobian(self, u: np.ndarray) -> float:
        """min det F over all quadrature points of the assembled tets."""
        H = el.displacement_gradient(self.G, self.element_displacement(u))
        return float(np.linalg.det(H + np.eye(3)).min())


def lame(scene: Scene, mesh: TetMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-tet mu, lambda (kPa) and density (kg/m^3) from the scene's tissues."""
    tissues = [scene.tissues[n] for n in mesh.tissue_names]
    E = np.array([t.youngs for t in tissues])[mesh.tissue]
    nu = np.array([t.poisson for t in tissues])[mesh.tissue]
    rho = np.array([t.density_kg_m3 for t in tissues])[mesh.tissue]
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu)), rho


def _constraints(scene: Scene, mesh: TetMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(fixed DOFs, guide DOFs (n_patch, 3), guide weights)."""
    fixed = []
    if scene.effects.fixed_bones:
        fixed.append((3 * mesh.node_sets["bones"][:, None] + np.arange(3)).ravel())
    if scene.effects.table:
        fixed.append(3 * mesh.node_sets["table"] + 2)
    patch, weight = guide_weights(mesh, scene)
    guide = 3 * patch[:, None] + np.arange(3)
    fixed = np.setdiff1d(np.concatenate(fixed) if fixed else np.array([], int), guide.ravel())
    return fixed, guide, weight


def build_problem(scene: Scene, mesh: TetMesh) -> Problem:
    """Assemble-ready data for the effects the scene switches on."""
    from skfem import Basis, ElementTetP2

    basis = Basis(skfem_mesh(mesh), ElementTetP2(), intorder=2)
    if not np.allclose(basis.doflocs.T, mesh.nodes, atol=1e-9 * np.abs(mesh.nodes).max()):
        raise ValueError("mesh nodes are not in scikit-fem's P2 DOF order; build it with mesh.from_vertices")
    tets = basis.element_dofs.T  # skfem local order, matching basis.basis below
    fixed, guide, weight = _constraints(scene, mesh)
    constrained = np.zeros(3 * len(mesh.nodes), bool)
    constrained[fixed] = constrained[guide.ravel()] = True
    active = ~constrained[(3 * tets[:, :, None] + np.arange(3))].reshape(len(tets), -1).all(axis=1)
    G = np.stack([basis.basis[a][0].grad for a in range(10)])  # (10, 3, n_tets, n_qp)
    G = np.ascontiguousarray(G.transpose(2, 3, 0, 1)[active])
    W = np.ascontiguousarray(basis.dx[active])
    mu, lam, rho = (x[active] for x in lame(scene, mesh))
    pattern = build_pattern(tets[active], len(mesh.nodes), np.flatnonzero(~constrained))
    body = None
    if scene.effects.gravity:
        N = np.stack([basis.basis[a][0].value for a in range(10)])[:, active]  # (10, n_active, n_qp)
        fz = -rho * G_MM_S2 * PA_TO_KPA_PER_MM
        fe = np.zeros((active.sum(), 10, 3))
        fe[:, :, 2] = np.einsum("aeq,eq->ea", N, W) * fz[:, None]
        body = assemble_vector(pattern, fe)
    return Problem(scene, mesh, G, W, mu, lam, pattern, fixed, guide, weight, body, active)
