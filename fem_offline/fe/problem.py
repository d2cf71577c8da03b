"""The discrete problem: P2 basis data, per-tet materials, constraints and loads for the effects a scene switches on.

Materials: materials.py; boundary conditions (bones, table, guide): boundary.py and guide.py;
gravity: gravity.py; the guide tip's contact with the wall: contact.py. Tets whose nodes are all fixed (the bones)
cannot change K_II and are not assembled.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fem_offline.fe import contact as ct
from fem_offline.fe import elasticity as el
from fem_offline.fe import guide, mixed
from fem_offline.fe.assembly import Pattern, build_pattern
from fem_offline.fe.boundary import constraints
from fem_offline.fe.gravity import body_force
from fem_offline.fe.materials import lame
from fem_offline.geometry.mesh import TetMesh, skfem_mesh
from fem_offline.scene import Scene


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
    contact: ct.Surface | None = None  # effects.guide_contact: the lumen faces the tip can touch
    contact_load: ct.Load | None = None  # where the tip is now (set by `at_guide`)
    pressure: mixed.Pressure | None = None  # solver.volumetric = "taylor_hood": the P1 pressure space

    @property
    def n_dofs(self) -> int:
        return self.pattern.n_dofs

    @property
    def free(self) -> np.ndarray:
        return self.pattern.free

    @property
    def nonlinear(self) -> bool:
        return self.scene.effects.geometric_nonlinearity

    @property
    def mean_dilatation(self) -> bool:
        """solver.volumetric = "mean_dilatation": the volumetric term per tet (elasticity.py)."""
        return self.scene.solver.volumetric == "mean_dilatation"

    @property
    def taylor_hood(self) -> bool:
        """solver.volumetric = "taylor_hood": P2/P1 with the pressure eliminated (mixed.py)."""
        return self.pressure is not None

    @property
    def superposable(self) -> bool:
        """Linear in the guide displacement: small strain and a glued guide (linear.py)."""
        return not self.nonlinear and self.contact is None

    def at_guide(self, displacement_mm: float, angle_deg: float, multipliers: np.ndarray | None = None) -> Problem:
        """This problem with the contact tip at (d, beta) and the given multipliers (zero if None)."""
        if self.contact is None:
            return self
        lam = np.zeros(self.contact.shape) if multipliers is None else multipliers
        centre = ct.centre(self.contact, self.scene.guide, displacement_mm, angle_deg)
        return replace(self, contact_load=ct.Load(centre, lam))

    def with_solver(self, **controls) -> Problem:
        """This problem with some of scene.solver's controls changed (e.g. max_step_mm, max_halvings)."""
        solver = self.scene.solver.model_copy(update=controls)
        return replace(self, scene=self.scene.model_copy(update={"solver": solver}))

    def dirichlet(self, displacement_mm: float, angle_deg: float) -> np.ndarray:
        """Prescribed displacement on all DOFs (zero where free): the guide's field d w a(beta)."""
        return guide.prescribed(self.scene.guide, dofs=self.guide_dofs, weight=self.guide_weight, n_dofs=self.n_dofs,
                                displacement_mm=displacement_mm, angle_deg=angle_deg)

    def element_displacement(self, u: np.ndarray) -> np.ndarray:
        return u[self.pattern.edofs].reshape(-1, 10, 3)

    def min_jacobian(self, u: np.ndarray) -> float:
        """min det F over all quadrature points of the assembled tets."""
        H = el.displacement_gradient(self.G, self.element_displacement(u))
        return float(np.linalg.det(H + np.eye(3)).min())


def build_problem(scene: Scene, mesh: TetMesh) -> Problem:
    """Assemble-ready data for the effects the scene switches on."""
    from skfem import Basis, ElementTetP2

    basis = Basis(skfem_mesh(mesh), ElementTetP2(), intorder=2)
    if not np.allclose(basis.doflocs.T, mesh.nodes, atol=1e-9 * np.abs(mesh.nodes).max()):
        raise ValueError("mesh nodes are not in scikit-fem's P2 DOF order; build it with mesh.from_vertices")
    tets = basis.element_dofs.T  # skfem local order, matching basis.basis below
    fixed, guide_dofs, weight = constraints(scene, mesh)
    constrained = np.zeros(3 * len(mesh.nodes), bool)
    constrained[fixed] = constrained[guide_dofs.ravel()] = True
    active = ~constrained[(3 * tets[:, :, None] + np.arange(3))].reshape(len(tets), -1).all(axis=1)
    G = np.stack([basis.basis[a][0].grad for a in range(10)])  # (10, 3, n_tets, n_qp)
    G = np.ascontiguousarray(G.transpose(2, 3, 0, 1)[active])
    W = np.ascontiguousarray(basis.dx[active])
    mu, lam, rho = (x[active] for x in lame(scene, mesh))
    pattern = build_pattern(tets[active], len(mesh.nodes), np.flatnonzero(~constrained))
    surface = None
    if scene.effects.guide_contact:
        deforming = [t.youngs for t in scene.tissues.values() if not (t.bone and scene.effects.fixed_bones)]
        surface = ct.build_surface(mesh, basis.mesh, tets, active, scene.guide, stiffest_youngs_kpa=max(deforming))
    body = None
    if scene.effects.gravity:
        N = np.stack([basis.basis[a][0].value for a in range(10)])[:, active]  # (10, n_active, n_qp)
        body = body_force(N=N, W=W, density_kg_m3=rho, pattern=pattern)
    pressure = None
    if scene.solver.volumetric == "taylor_hood":
        from skfem import ElementTetP1

        p1 = Basis(basis.mesh, ElementTetP1(), quadrature=basis.quadrature)  # the same points
        N = np.stack([np.asarray(p1.basis[a][0]) for a in range(4)], axis=-1)[active]  # (n_active, n_qp, 4)
        pressure = mixed.pressure_space(p1.element_dofs.T[active], N, W, mesh.tissue[active], lam, pattern.edofs)
    problem = Problem(scene, mesh, G, W, mu, lam, pattern, fixed, guide_dofs, weight, body, active, surface,
                      pressure=pressure)
    return problem.at_guide(0.0, 0.0)
