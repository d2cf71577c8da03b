"""Small drivers over the product's kernels for verification problems on plain skfem meshes."""

import numpy as np
from skfem import Basis, ElementTetP2

from fem_offline import elasticity as el
from fem_offline.assembly import apply_matrix, assemble_matrix, assemble_vector, build_pattern
from fem_offline.linsolve import Factor


def p2_data(mesh, intorder=2):
    """P2 nodes (n, 3), element nodes (m, 10), gradients G (m, q, 10, 3), weights W (m, q), basis."""
    basis = Basis(mesh, ElementTetP2(), intorder=intorder)
    G = np.stack([basis.basis[a][0].grad for a in range(10)]).transpose(2, 3, 0, 1)
    return basis.doflocs.T, basis.element_dofs.T, np.ascontiguousarray(G), basis.dx, basis


def lame_params(youngs, poisson, n):
    mu = youngs / (2 * (1 + poisson))
    lam = youngs * poisson / ((1 + poisson) * (1 - 2 * poisson))
    return np.full(n, mu), np.full(n, lam)


def solve_linear(tets, n_nodes, G, W, mu, lam, fixed_dofs, g, f_ext):
    """u with u[fixed] = g[fixed] and K u = f_ext on the free DOFs."""
    free = np.setdiff1d(np.arange(3 * n_nodes), fixed_dofs)
    pattern = build_pattern(tets, n_nodes, free)
    Ke = el.linear_stiffness(G, W, mu, lam)
    u = np.where(np.isin(np.arange(3 * n_nodes), fixed_dofs), g, 0.0)
    rhs = f_ext - apply_matrix(pattern, Ke, u)
    u[free] = Factor(assemble_matrix(pattern, Ke)).solve(rhs[free])
    return u, pattern


def internal_force_nh(pattern, G, W, mu, lam, u):
    H = el.displacement_gradient(G, u[pattern.edofs].reshape(-1, 10, 3))
    P, _, _ = el.neo_hookean_stress(H, mu, lam)
    return assemble_vector(pattern, el.internal_force(G, W, P))
