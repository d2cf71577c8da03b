"""The mean-dilatation element (solver.volumetric = "mean_dilatation"): its force is the derivative
of its energy, its tangent the derivative of its force, its small-strain limit the B-bar stiffness,
it passes the patch test, and it relieves volumetric locking where the pointwise element locks."""

import numpy as np
import pytest
from skfem import MeshTet

from fem_offline.fe import elasticity as el
from fem_offline.fe.assembly import assemble_matrix, assemble_vector, build_pattern

from ..fe_helpers import internal_force_nh, lame_params, lame_sphere_error, p2_data, solve_linear

A = np.array([[0.010, -0.004, 0.002], [0.003, 0.008, -0.005], [-0.002, 0.006, -0.009]])


def _cube(n):
    x = np.linspace(0.0, 1.0, n + 1)
    return MeshTet.init_tensor(x, x, x)


def _setup(n=2):
    nodes, tets, G, W, _ = p2_data(_cube(n))
    mu, lam = lame_params(10.0, 0.495, len(tets))
    mu[::2], lam[::2] = 3 * mu[::2], 3 * lam[::2]  # two tissues
    pattern = build_pattern(tets, len(nodes), np.arange(3 * len(nodes)))
    u = (nodes @ (20 * A).T + 0.08 * np.sin(4 * nodes[:, ::-1])).ravel()  # J from below 0.9 to above 1.1
    return nodes, G, W, mu, lam, pattern, u


def _energy(pattern, G, W, mu, lam, u, md, nonlinear=True):
    H = el.displacement_gradient(G, u[pattern.edofs].reshape(-1, 10, 3))
    if nonlinear:
        J = np.linalg.det(H + np.eye(3))
        return el.neo_hookean_energy(H, J, W, mu, lam, md)
    return el.linear_energy(H, W, mu, lam, md)


def _linear_force(pattern, G, W, mu, lam, u, md):
    H = el.displacement_gradient(G, u[pattern.edofs].reshape(-1, 10, 3))
    return assemble_vector(pattern, el.internal_force(G, W, el.linear_stress(H, mu, lam, W if md else None)))


@pytest.mark.parametrize("nonlinear", [True, False])
def test_force_is_the_derivative_of_the_energy(nonlinear):
    """f(u) . v = (Pi(u + h v) - Pi(u - h v)) / 2h, and the mean-dilatation energy differs from the pointwise one."""
    _, G, W, mu, lam, pattern, u = _setup()
    if not nonlinear:
        u = 0.05 * u
    v = np.random.default_rng(2).normal(size=u.size)
    h = 1e-6
    force = internal_force_nh if nonlinear else _linear_force
    f = force(pattern, G, W, mu, lam, u, md=True)
    fd = (_energy(pattern, G, W, mu, lam, u + h * v, True, nonlinear)
          - _energy(pattern, G, W, mu, lam, u - h * v, True, nonlinear)) / (2 * h)
    assert f @ v == pytest.approx(fd, rel=1e-6)
    pointwise = _energy(pattern, G, W, mu, lam, u, False, nonlinear)
    assert abs(_energy(pattern, G, W, mu, lam, u, True, nonlinear) - pointwise) > 1e-3 * abs(pointwise)


def test_tangent_is_the_derivative_of_the_force():
    """K(u) v = (f(u + h v) - f(u - h v)) / 2h at a finite, heterogeneous deformation; K symmetric."""
    _, G, W, mu, lam, pattern, u = _setup()
    v = np.random.default_rng(1).normal(size=u.size)
    H = el.displacement_gradient(G, u[pattern.edofs].reshape(-1, 10, 3))
    _, Finv, J = el.neo_hookean_stress(H, mu, lam, W)
    assert J.min() < 0.9 and J.max() > 1.1
    K = assemble_matrix(pattern, el.neo_hookean_tangent(G, W, Finv, J, mu, lam, md=True))
    h = 1e-6
    fd = (internal_force_nh(pattern, G, W, mu, lam, u + h * v, md=True)
          - internal_force_nh(pattern, G, W, mu, lam, u - h * v, md=True)) / (2 * h)
    np.testing.assert_allclose(K @ v, fd, atol=1e-6 * np.abs(fd).max())
    np.testing.assert_allclose((K - K.T).toarray(), 0, atol=1e-12 * np.abs(K).max())


def test_small_strain_limit_is_the_b_bar_stiffness():
    """At F = I the nonlinear tangent is the linear stiffness, and the linear one is the derivative
    of the linear force; its volumetric part has rank one per tet (one constraint, not four)."""
    nodes, G, W, mu, lam, pattern, _ = _setup()
    shape = W.shape + (3, 3)
    K0 = el.neo_hookean_tangent(G, W, np.broadcast_to(np.eye(3), shape), np.ones(W.shape), mu, lam, md=True)
    Klin = el.linear_stiffness(G, W, mu, lam, md=True)
    np.testing.assert_allclose(K0, Klin, atol=1e-10 * np.abs(Klin).max())
    u = 0.01 * np.random.default_rng(3).normal(size=3 * len(nodes))
    f = _linear_force(pattern, G, W, mu, lam, u, md=True)
    np.testing.assert_allclose(assemble_matrix(pattern, Klin) @ u, f, atol=1e-10 * np.abs(f).max())
    vol = (el.linear_stiffness(G, W, np.zeros_like(mu), lam, md=True)).reshape(len(W), 30, 30)
    assert np.all(np.linalg.matrix_rank(vol[:5], tol=1e-9 * np.abs(vol).max()) == 1)


def test_patch_test():
    """u = A X on the boundary is reproduced exactly inside, small strain and finite (F = I + 20 A)."""
    nodes, tets, G, W, _ = p2_data(_cube(3))
    mu, lam = lame_params(10.0, 0.495, len(tets))
    boundary = np.flatnonzero(np.any((nodes < 1e-12) | (nodes > 1 - 1e-12), axis=1))
    fixed = (3 * boundary[:, None] + np.arange(3)).ravel()
    interior = np.setdiff1d(np.arange(3 * len(nodes)), fixed)
    exact = (nodes @ A.T).ravel()
    u, pattern = solve_linear(tets, len(nodes), G, W, mu, lam, fixed, exact, np.zeros_like(exact), md=True)
    np.testing.assert_allclose(u[interior], exact[interior], atol=1e-12)
    f = internal_force_nh(pattern, G, W, mu, lam, 20 * exact, md=True)
    assert np.abs(f[interior]).max() < 1e-10 * np.abs(f[fixed]).max()


def test_it_relieves_locking_where_the_pointwise_element_locks():
    """Lame's thick sphere on a coarse mesh at Table 1's nu = 0.495 (lambda / mu = 99): the pointwise
    P2 element is 2.0 % off the exact radial displacement, the mean-dilatation one 0.8 %; at
    nu = 0.4999 (lambda / mu = 5000) 3.2 % against 0.8 %: its error does not grow with lambda."""
    pointwise, md = lame_sphere_error(0.495, size=0.6), lame_sphere_error(0.495, size=0.6, md=True)
    assert md < 0.01
    assert pointwise > 2 * md
    assert lame_sphere_error(0.4999, size=0.6, md=True) < 1.1 * md
