"""The Taylor-Hood element (solver.volumetric = "taylor_hood", fem_offline/fe/mixed.py): its force is the
derivative of its energy and its reduced tangent the derivative of its force, it passes the patch
test, the pressure is P1 per tissue, the saddle-point solve agrees with Newton's CG on the reduced
Hessian, and it neither locks nor loses accuracy as lambda grows."""

import numpy as np
import pytest
from skfem import MeshTet

from fem_offline.fe import elasticity as el
from fem_offline.fe import mixed
from fem_offline.fe import newton as nt
from fem_offline.fe.assembly import apply_matrix
from fem_offline.fe.linear import linear_modes, superpose
from fem_offline.fe.newton import FactorCache
from fem_offline.fe.problem import build_problem

from ..fe_helpers import build_pattern, lame_params, lame_sphere_error, p2_data, solve_linear, taylor_hood_space

A = np.array([[0.010, -0.004, 0.002], [0.003, 0.008, -0.005], [-0.002, 0.006, -0.009]])


def _problem(scene, mesh, nonlinear=True):
    effects = scene.effects.model_copy(update={"geometric_nonlinearity": nonlinear})
    solver = scene.solver.model_copy(update={"volumetric": "taylor_hood"})
    return build_problem(scene.model_copy(update={"effects": effects, "solver": solver}), mesh)


@pytest.fixture(scope="module")
def problems(tiny_scene, tiny_mesh):
    return {nonlinear: _problem(tiny_scene, tiny_mesh, nonlinear) for nonlinear in (True, False)}


def _state(p, scale, seed=0):
    rng = np.random.default_rng(seed)
    u, v = np.zeros(p.n_dofs), np.zeros(p.n_dofs)
    u[p.free] = scale * rng.normal(size=p.free.size)
    v[p.free] = rng.normal(size=p.free.size)
    return u, v


@pytest.mark.parametrize("nonlinear", [True, False])
def test_force_and_tangent_are_derivatives(problems, nonlinear):
    """r . v = dPi/dh and (K + G^T M^-1 G) v = dr/dh by central differences, at a state with J from
    about 0.8 to 1.2; the pressure is the projection of lambda ln J (so Pi is not the pointwise one)."""
    p = problems[nonlinear]
    u, v = _state(p, 0.05 if nonlinear else 0.01)
    ev = nt.residual(p, u)
    if nonlinear:
        assert ev.J.min() < 0.9 and ev.J.max() > 1.1
    h = 1e-6
    plus, minus = nt.residual(p, u + h * v), nt.residual(p, u - h * v)
    assert ev.r @ v == pytest.approx((plus.pi - minus.pi) / (2 * h), rel=1e-6)
    Kv = apply_matrix(p.pattern, nt._tangent(p, ev), v) + mixed.reduced_product(p.pressure, nt._coupling(p, ev), v)
    fd = (plus.r - minus.r) / (2 * h)
    np.testing.assert_allclose(Kv[p.free], fd[p.free], atol=1e-6 * np.abs(fd[p.free]).max())


def test_pressure_is_p1_per_tissue(problems, tiny_mesh):
    """One pressure unknown per (corner node, tissue) of the assembled tets, and the mass matrix is
    int N N / lambda: its sum is int 1 / lambda over the assembled tets."""
    p = problems[True]
    corners = tiny_mesh.tets[p.active][:, :4]
    tissue = tiny_mesh.tissue[p.active]
    expected = sum(np.unique(corners[tissue == t]).size for t in np.unique(tissue))
    assert p.pressure.n == expected
    assert p.pressure.mass.sum() == pytest.approx(float((p.W.sum(axis=1) / p.lam).sum()), rel=1e-12)


def test_saddle_point_solve_agrees_with_newton_on_the_reduced_hessian(problems):
    """The glued small-strain problem two ways: linear_modes' one saddle-point solve (superposition),
    and Newton, whose corrections go through CG on the reduced Hessian as an operator."""
    p = problems[False]
    assert p.superposable
    modes = linear_modes(p)
    u, _ = nt.newton(p, np.zeros(p.n_dofs), p.dirichlet(3.0, 5.0), FactorCache())
    exact = superpose(modes, 3.0, 5.0).ravel()
    assert np.abs(u - exact).max() < 1e-7 * np.abs(exact).max()


def _cube(n):
    x = np.linspace(0.0, 1.0, n + 1)
    return MeshTet.init_tensor(x, x, x)


def test_patch_test():
    """u = A X on the boundary is reproduced exactly inside, with the tets split into two tissues (two
    pressure fields), in small strain and at finite strain (F = I + 20 A: ln J is constant, in P1)."""
    nodes, tets, G, W, basis = p2_data(_cube(3))
    mu, lam = lame_params(10.0, 0.495, len(tets))
    tissue = np.arange(len(tets)) % 2
    boundary = np.flatnonzero(np.any((nodes < 1e-12) | (nodes > 1 - 1e-12), axis=1))
    fixed = (3 * boundary[:, None] + np.arange(3)).ravel()
    interior = np.setdiff1d(np.arange(3 * len(nodes)), fixed)
    exact = (nodes @ A.T).ravel()
    u, pattern = solve_linear(tets, len(nodes), G, W, mu, lam, fixed, exact, np.zeros_like(exact), basis=basis,
                              tissue=tissue)
    np.testing.assert_allclose(u[interior], exact[interior], atol=1e-12)
    pressure = taylor_hood_space(basis, tets, W, lam, build_pattern(tets, len(nodes), interior), tissue)
    assert pressure.n > len(np.unique(tets[:, :4]))
    H = el.displacement_gradient(G, (20 * exact)[pattern.edofs].reshape(-1, 10, 3))
    P, _, J = el.neo_hookean_stress(H, mu, lam, pressure=lambda J: pressure.project(W, np.log(J))[2])
    np.testing.assert_allclose(P, el.neo_hookean_stress(H, mu, lam)[0], atol=1e-9 * np.abs(P).max())


def test_it_does_not_lock():
    """Lame's thick sphere on a coarse mesh: at nu = 0.495 the pointwise P2 element is 2.0 % off the
    exact radial displacement and Taylor-Hood 0.73 % (the faceted inner sphere's share, where the
    mean-dilatation element is 0.76 %); at nu = 0.4999 (lambda / mu = 5000) Taylor-Hood stays at
    0.74 % where the pointwise element goes to 3.2 %."""
    th, pointwise = lame_sphere_error(0.495, size=0.6, taylor_hood=True), lame_sphere_error(0.495, size=0.6)
    assert th < 0.0075
    assert pointwise > 2.5 * th
    assert th <= lame_sphere_error(0.495, size=0.6, md=True)
    assert lame_sphere_error(0.4999, size=0.6, taylor_hood=True) < 1.02 * th


def test_a_float32_saddle_step_the_line_search_rejects_is_redone_with_float64_factors(problems, monkeypatch):
    """The saddle-point factors are float32 (newton.SINGLE_FACTORS); where their step lowers no energy (here:
    made an ascent direction), Newton redoes that iteration with float64 factors and keeps them, instead of
    failing the line search. From a perturbed equilibrium with the guide in place (every step must pass Armijo)."""
    from ..fe_helpers import newton_with_one_uphill_step

    p = problems[True]
    u, g, stats, factor, spoiled = newton_with_one_uphill_step(p, monkeypatch, lambda f: f.float32)
    assert spoiled and isinstance(factor, mixed.SaddleFactor) and not factor.float32
    assert stats.residual <= p.scene.solver.rtol
    assert np.abs(u - g).max() < 1e-6 * np.abs(g).max()
