"""The linear model: superposing the unit fields is the linear solve, case by case and on a grid."""

import numpy as np

from fem_offline.fe.linear import linear_modes, superpose
from fem_offline.fe.newton import FactorCache, newton


def test_superposition_on_a_grid_equals_a_direct_solve_of_each_case(tiny_linear_problem):
    """u_0 + d (cos b U_axis + sin b U_perp) over d (2, 1) x beta (1, 3) equals Newton's solve of
    K u = f with u_D = d w a(beta) (one iteration on the linear model), case by case, to 1e-12
    of max |u| (measured 8e-15)."""
    p = tiny_linear_problem
    d_mm, beta_deg = np.array([[2.5], [10.0]]), np.array([[-10.0, 3.0, 10.0]])
    grid = superpose(linear_modes(p), d_mm, beta_deg)
    assert grid.shape == (2, 3, len(p.mesh.nodes), 3)
    for i, d in enumerate(d_mm[:, 0]):
        for j, b in enumerate(beta_deg[0]):
            direct, _ = newton(p, np.zeros(p.n_dofs), p.dirichlet(d, b), FactorCache())
            np.testing.assert_allclose(grid[i, j], direct.reshape(-1, 3), rtol=0, atol=1e-12 * np.abs(direct).max())
