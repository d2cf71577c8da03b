"""FE verification against exact solutions: patch test, Lame sphere, convergence rate."""

import numpy as np
import pytest
from skfem import ElementTetP2, LinearForm, MeshTet

from fem_offline.fe import elasticity as el

from ..fe_helpers import internal_force_nh, lame_params, lame_sphere_error, p2_data, solve_linear


def _cube(n):
    x = np.linspace(0.0, 1.0, n + 1)
    return MeshTet.init_tensor(x, x, x)


def _boundary_nodes(nodes):
    return np.flatnonzero(np.any((nodes < 1e-12) | (nodes > 1 - 1e-12), axis=1))


A = np.array([[0.010, -0.004, 0.002], [0.003, 0.008, -0.005], [-0.002, 0.006, -0.009]])
C = np.array([0.1, -0.2, 0.05])


def test_patch_test_linear():
    """u = A X + c on the boundary of a tetrahedralised cube is reproduced exactly inside (nu = 0.495)."""
    nodes, tets, G, W, _ = p2_data(_cube(3))
    mu, lam = lame_params(10.0, 0.495, len(tets))
    exact = (nodes @ A.T + C).ravel()
    fixed = (3 * _boundary_nodes(nodes)[:, None] + np.arange(3)).ravel()
    u, _ = solve_linear(tets, len(nodes), G, W, mu, lam, fixed, exact, np.zeros_like(exact))
    interior = np.setdiff1d(np.arange(exact.size), fixed)
    assert interior.size > 0
    np.testing.assert_allclose(u[interior], exact[interior], atol=1e-12)


def test_patch_test_neo_hookean():
    """A homogeneous finite deformation (F = I + 20 A) has constant P: interior forces vanish."""
    nodes, tets, G, W, _ = p2_data(_cube(3))
    mu, lam = lame_params(10.0, 0.495, len(tets))
    exact = (nodes @ (20 * A).T).ravel()
    fixed = (3 * _boundary_nodes(nodes)[:, None] + np.arange(3)).ravel()
    _, pattern = solve_linear(tets, len(nodes), G, W, mu, lam, fixed, exact, np.zeros_like(exact))
    f = internal_force_nh(pattern, G, W, mu, lam, exact)
    interior = np.setdiff1d(np.arange(exact.size), fixed)
    scale = np.abs(f[fixed]).max()
    assert scale > 1e-3
    assert np.abs(f[interior]).max() < 1e-10 * scale


def test_neo_hookean_tangent_is_the_derivative_of_the_internal_force():
    """K(u) v = (f(u + h v) - f(u - h v)) / 2h at a finite, heterogeneous deformation (two tissues,
    J from below 0.9 to above 1.1): the tangent is exact, so Newton converges quadratically."""
    from fem_offline.fe.assembly import assemble_matrix, build_pattern

    nodes, tets, G, W, _ = p2_data(_cube(2))
    mu, lam = lame_params(10.0, 0.495, len(tets))
    mu[::2], lam[::2] = 3 * mu[::2], 3 * lam[::2]
    rng = np.random.default_rng(1)
    u = (nodes @ (20 * A).T + 0.08 * np.sin(4 * nodes[:, ::-1])).ravel()
    v = rng.normal(size=u.size)
    pattern = build_pattern(tets, len(nodes), np.arange(u.size))
    H = el.displacement_gradient(G, u[pattern.edofs].reshape(-1, 10, 3))
    _, Finv, J = el.neo_hookean_stress(H, mu, lam)
    assert J.min() < 0.9 and J.max() > 1.1
    K = assemble_matrix(pattern, el.neo_hookean_tangent(G, W, Finv, J, mu, lam))
    h = 1e-6
    fd = (internal_force_nh(pattern, G, W, mu, lam, u + h * v)
          - internal_force_nh(pattern, G, W, mu, lam, u - h * v)) / (2 * h)
    np.testing.assert_allclose(K @ v, fd, atol=1e-6 * np.abs(fd).max())
    np.testing.assert_allclose((K - K.T).toarray(), 0, atol=1e-12 * np.abs(K).max())


def test_lame_sphere_nearly_incompressible():
    """Thick sphere a=1, b=2 under internal pressure p, nu = 0.495 (where linear tets lock): within 1 %."""
    assert lame_sphere_error(0.495) < 0.01


def _manufactured_force(x, mu, lam):
    """f = -div sigma for u_i = sin(pi x) sin(pi y) sin(pi z), i = 1..3."""
    s, c = np.sin(np.pi * x), np.cos(np.pi * x)
    sss = s[0] * s[1] * s[2]
    grad_div = np.pi**2 * np.stack([
        -sss + c[0] * c[1] * s[2] + c[0] * s[1] * c[2],
        c[0] * c[1] * s[2] - sss + s[0] * c[1] * c[2],
        c[0] * s[1] * c[2] + s[0] * c[1] * c[2] - sss,
    ])
    return 3 * np.pi**2 * mu * sss - (lam + mu) * grad_div


def _l2_error(n):
    mesh = _cube(n)
    nodes, tets, G, W, _ = p2_data(mesh)
    mu, lam = lame_params(1.0, 0.3, len(tets))
    f = np.zeros(3 * len(nodes))
    _, _, _, _, fine = p2_data(mesh, intorder=6)
    for i in range(3):
        f[i::3] = LinearForm(lambda v, w, i=i: _manufactured_force(w.x, mu[0], lam[0])[i] * v).assemble(fine)
    fixed = (3 * _boundary_nodes(nodes)[:, None] + np.arange(3)).ravel()
    u, _ = solve_linear(tets, len(nodes), G, W, mu, lam, fixed, np.zeros_like(f), f)
    x = fine.global_coordinates()
    exact = np.prod(np.sin(np.pi * x), axis=0)
    err2 = sum(np.sum((fine.interpolate(u[i::3]) - exact) ** 2 * fine.dx) for i in range(3))
    return np.sqrt(err2)


def test_p2_l2_convergence_rate_is_three():
    """log L2 error vs log h has slope ~3 for quadratic elements (scikit-fem's convergence test idiom)."""
    hs = np.array([1 / 2, 1 / 4, 1 / 8])
    errs = np.array([_l2_error(round(1 / h)) for h in hs])
    rate = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert rate == pytest.approx(3.0, abs=0.3)
    assert errs[-1] < 2e-3


def test_einsum_stiffness_equals_scikit_fem_bilinear_form():
    """The vectorised kernel assembles the same K as scikit-fem's BilinearForm (per-element lambda, mu)."""
    from skfem import Basis, BilinearForm, ElementVector, asm
    from skfem.helpers import ddot, div, sym_grad

    from fem_offline.fe.assembly import assemble_matrix, build_pattern

    mesh = _cube(2)
    nodes, tets, G, W, _ = p2_data(mesh)
    rng = np.random.default_rng(1)
    mu, lam = rng.uniform(1, 5, len(tets)), rng.uniform(10, 500, len(tets))
    pattern = build_pattern(tets, len(nodes), np.arange(3 * len(nodes)))
    K = assemble_matrix(pattern, el.linear_stiffness(G, W, mu, lam)).toarray()

    @BilinearForm
    def linear_elasticity(u, v, w):
        return w.lam * div(u) * div(v) + 2.0 * w.mu * ddot(sym_grad(u), sym_grad(v))

    vb = Basis(mesh, ElementVector(ElementTetP2()), intorder=2)
    nq = vb.dx.shape[1]
    ref = asm(linear_elasticity, vb, lam=np.repeat(lam[:, None], nq, 1), mu=np.repeat(mu[:, None], nq, 1)).toarray()
    # scikit-fem numbers vector DOFs node-major (3 * node + component), as the kernel does.
    np.testing.assert_allclose(K, ref, atol=1e-9 * np.abs(ref).max())


def test_pattern_assembles_what_scipy_sums_when_the_free_set_splits_nodes():
    """K_II through the precomputed slots equals scipy's COO sum over the free rows and columns,
    also where a node keeps only some components free (the table's u_z = 0)."""
    import scipy.sparse as sp

    from fem_offline.fe.assembly import assemble_matrix, build_pattern

    nodes, tets, _, _, _ = p2_data(_cube(2))
    rng = np.random.default_rng(2)
    constrained = rng.choice(3 * len(nodes), size=len(nodes), replace=False)
    free = np.setdiff1d(np.arange(3 * len(nodes)), constrained)
    Ke = rng.standard_normal((len(tets), 10, 3, 10, 3))
    K = assemble_matrix(build_pattern(tets, len(nodes), free), Ke)

    edofs = (3 * tets[:, :, None] + np.arange(3)).reshape(len(tets), 30)
    rows = np.broadcast_to(edofs[:, :, None], (len(tets), 30, 30)).ravel()
    cols = np.broadcast_to(edofs[:, None, :], (len(tets), 30, 30)).ravel()
    n = 3 * len(nodes)
    ref = sp.coo_matrix((Ke.ravel(), (rows, cols)), shape=(n, n)).tocsr()[free][:, free]
    ref.sum_duplicates()
    ref.sort_indices()
    assert K.has_sorted_indices
    np.testing.assert_array_equal(K.indptr, ref.indptr)
    np.testing.assert_array_equal(K.indices, ref.indices)
    np.testing.assert_allclose(K.data, ref.data, atol=1e-12)
