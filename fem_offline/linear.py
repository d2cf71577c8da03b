"""The linear (small-strain) model: every case is a superposition of three fields.

    u(d, beta) = u_0 + d (cos beta U_axis + sin beta U_perp)

U_axis and U_perp answer a unit guide displacement at beta = 0 and 90 deg (the prescribed field
d w a(beta) is linear in d and a(beta) = cos beta a(0) + sin beta a(90)); u_0 is the gravity sag
K_II u_0 = f_gravity, or zero. One factorisation of K_II serves every case.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import elasticity as el
from .assembly import apply_matrix, assemble_matrix
from .linsolve import factorise, rigid_body_modes
from .problem import Problem


class LinearModes(NamedTuple):
    u0: np.ndarray  # (n_dofs,) gravity sag or zero
    u_axis: np.ndarray  # (n_dofs,) unit guide displacement at beta = 0
    u_perp: np.ndarray  # (n_dofs,) unit guide displacement at beta = 90 deg


def linear_modes(problem: Problem) -> LinearModes:
    """u_0, U_axis and U_perp: one factorisation of K_II, two unit solves (and one for gravity)."""
    p = problem
    Ke = el.linear_stiffness(p.G, p.W, p.mu, p.lam)
    factor = factorise(assemble_matrix(p.pattern, Ke), near_nullspace=rigid_body_modes(p.mesh.nodes)[p.free])
    fields = []
    for beta in (0.0, 90.0):
        g = p.dirichlet(1.0, beta)
        u = g.copy()
        u[p.free] = factor.solve(-apply_matrix(p.pattern, Ke, g)[p.free])
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
