"""The linear (small-strain) model: every case is a superposition of three fields.

    u(d, beta) = u_0 + d (cos beta U_axis + sin beta U_perp)

U_axis and U_perp answer a unit guide displacement at beta = 0 and 90 deg (the prescribed field
d w a(beta) is linear in d and a(beta) = cos beta a(0) + sin beta a(90)); u_0 is the gravity sag
K_II u_0 = f_gravity, or zero. One factorisation of K_II serves every case.

The model's validity is limited: small strain does not keep det F = det(I + grad u) > 0, so a
large enough push turns elements inside out (on the default phantom, in the rectal wall under the
guide tip; docs/linear_validity.md). Along one angle grad u is affine in d, so det F is a cubic in d
at every quadrature point (`det_f_cubic`): every case's min det F costs a polynomial evaluation.
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from fem_offline.fe import elasticity as el
from fem_offline.fe import mixed
from fem_offline.fe.assembly import apply_matrix, assemble_matrix
from fem_offline.fe.linsolve import factorise, rigid_body_modes
from fem_offline.fe.problem import Problem


class LinearModes(NamedTuple):
    u0: np.ndarray  # (n_dofs,) gravity sag or zero
    u_axis: np.ndarray  # (n_dofs,) unit guide displacement at beta = 0
    u_perp: np.ndarray  # (n_dofs,) unit guide displacement at beta = 90 deg


def linear_modes(problem: Problem) -> LinearModes:
    """u_0, U_axis and U_perp: one factorisation of K_II, two unit solves (and one for gravity)."""
    p = problem
    if p.taylor_hood:  # shear stiffness + the pressure's G^T M^-1 G, solved through the saddle point (mixed.py)
        Ke = el.linear_stiffness(p.G, p.W, p.mu, np.zeros_like(p.lam))
        G = p.pressure.coupling(p.W, p.G, p.n_dofs)
        factor = mixed.Tangent(assemble_matrix(p.pattern, Ke), G[:, p.free].tocsr(), p.pressure).factorise()

        def apply(v):
            return apply_matrix(p.pattern, Ke, v) + mixed.reduced_product(p.pressure, G, v)
    else:
        Ke = el.linear_stiffness(p.G, p.W, p.mu, p.lam, p.mean_dilatation)
        factor = factorise(assemble_matrix(p.pattern, Ke), near_nullspace=rigid_body_modes(p.mesh.nodes)[p.free])

        def apply(v):
            return apply_matrix(p.pattern, Ke, v)
    fields = []
    for beta in (0.0, 90.0):
        g = p.dirichlet(1.0, beta)
        u = g.copy()
        u[p.free] = factor.solve(-apply(g)[p.free])
        fields.append(u)
    u0 = np.zeros(p.n_dofs)
    if p.body_force is not None:
        u0[p.free] = factor.solve(p.body_force[p.free])
    return LinearModes(u0, fields[0], fields[1])


def superpose(modes: LinearModes, displacement_mm, angle_deg) -> np.ndarray:
    """u = u_0 + d (cos beta U_axis + sin beta U_perp) for each (d, beta).

    d and beta are scalars or arrays that broadcast together; the result is (*shape, n_nodes, 3)
    for their broadcast shape, (n_nodes, 3) for one case.
    """
    d, b = np.broadcast_arrays(np.asarray(displacement_mm, dtype=np.float64), np.deg2rad(angle_deg))
    shape = d.shape
    d, b = d[..., None], b[..., None]
    u = modes.u0 + d * (np.cos(b) * modes.u_axis + np.sin(b) * modes.u_perp)
    return u.reshape(*shape, -1, 3)


def _cofactor(M: np.ndarray) -> np.ndarray:
    """Cofactor matrices of (..., 3, 3): row i is the cross product of the other two rows (det M = M_0 . cof_0)."""
    return np.stack([np.cross(M[..., 1, :], M[..., 2, :]), np.cross(M[..., 2, :], M[..., 0, :]),
                     np.cross(M[..., 0, :], M[..., 1, :])], axis=-2)


def det_f_cubic(problem: Problem, modes: LinearModes, angle_deg: float) -> np.ndarray:
    """Coefficients (4, n_active, n_qp) of det F(d) = c_0 + c_1 d + c_2 d^2 + c_3 d^3 at angle beta.

    grad u = A + d B with A = grad u_0, B = grad (cos beta U_axis + sin beta U_perp); det is
    multilinear in the rows, so with M = I + A:
        det(M + d B) = det M + d cof(M) : B + d^2 M : cof(B) + d^3 det B
    """
    def grad(u: np.ndarray) -> np.ndarray:  # (n_active, n_qp, 3, 3)
        return el.displacement_gradient(problem.G, problem.element_displacement(u))

    b = np.deg2rad(angle_deg)
    M = np.eye(3) + grad(modes.u0)
    B = grad(np.cos(b) * modes.u_axis + np.sin(b) * modes.u_perp)
    return np.stack([np.linalg.det(M), np.einsum("eqij,eqij->eq", _cofactor(M), B),
                     np.einsum("eqij,eqij->eq", M, _cofactor(B)), np.linalg.det(B)])


def det_f(problem: Problem, modes: LinearModes, displacements_mm, angle_deg: float) -> np.ndarray:
    """det(I + grad u) (n_d, n_active, n_qp) at every quadrature point of the assembled tets,
    for each d at one angle."""
    c = det_f_cubic(problem, modes, angle_deg)
    d = np.asarray(displacements_mm, dtype=np.float64)[:, None, None]
    return c[0] + d * (c[1] + d * (c[2] + d * c[3]))


def min_det_f(problem: Problem, modes: LinearModes, displacements_mm, angle_deg: float) -> np.ndarray:
    """min det F (n_d,) over all quadrature points for each d at one angle (= Problem.min_jacobian of each case)."""
    c = det_f_cubic(problem, modes, angle_deg)  # one d at a time: (n_d, n_active, n_qp) is large at paper scale
    return np.array([(c[0] + d * (c[1] + d * (c[2] + d * c[3]))).min() for d in np.atleast_1d(displacements_mm)])


def measured(problem: Problem, u: np.ndarray, stats):
    """A solve's Stats with min det F measured on u when the model is linear (superposition does not measure it)."""
    return stats if problem.nonlinear else replace(stats, min_det_f=problem.min_jacobian(np.ravel(u)))
