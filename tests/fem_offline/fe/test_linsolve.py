"""Linear solvers: AMG-CG (where PARDISO's factors do not fit) and PARDISO refactorisation."""

import numpy as np
import pytest

from fem_offline.fe import elasticity as el
from fem_offline.fe.assembly import apply_matrix, assemble_matrix
from fem_offline.fe.linsolve import AmgSolve, Factor, factorise, rigid_body_modes


def test_rigid_body_modes_are_in_the_nullspace_of_the_unconstrained_operator(tiny_linear_problem):
    """K(all DOFs) B = 0: rigid motions strain nothing (checked through the element kernel)."""
    p = tiny_linear_problem
    B = rigid_body_modes(p.mesh.nodes)
    Ke = el.linear_stiffness(p.G, p.W, p.mu, p.lam)
    scale = np.abs(apply_matrix(p.pattern, Ke, p.dirichlet(1.0, 0.0))).max()
    for k in range(6):
        assert np.abs(apply_matrix(p.pattern, Ke, B[:, k])).max() < 1e-9 * scale * np.abs(B[:, k]).max()


def test_amg_cg_matches_pardiso_on_the_phantom(tiny_linear_problem):
    p = tiny_linear_problem
    Ke = el.linear_stiffness(p.G, p.W, p.mu, p.lam)
    K = assemble_matrix(p.pattern, Ke)
    rhs = -apply_matrix(p.pattern, Ke, p.dirichlet(10.0, 10.0))[p.free]
    amg = factorise(K, near_nullspace=rigid_body_modes(p.mesh.nodes)[p.free], amg_min_dofs=0)
    assert isinstance(amg, AmgSolve)
    u_amg, u_direct = amg.solve(rhs), Factor(K).solve(rhs)
    assert np.abs(u_amg - u_direct).max() < 1e-6 * np.abs(u_direct).max()
    assert np.linalg.norm(K @ u_amg - rhs) <= 1e-9 * np.linalg.norm(rhs)
    assert 0 < amg.iterations[0] < 500


def test_small_systems_stay_direct(tiny_linear_problem):
    p = tiny_linear_problem
    K = assemble_matrix(p.pattern, el.linear_stiffness(p.G, p.W, p.mu, p.lam))
    assert isinstance(factorise(K, near_nullspace=rigid_body_modes(p.mesh.nodes)[p.free]), Factor)


def test_refactor_reuses_the_analysis_and_gives_a_fresh_factors_answer(tiny_linear_problem):
    p = tiny_linear_problem
    Ke = el.linear_stiffness(p.G, p.W, p.mu, p.lam)
    K = assemble_matrix(p.pattern, Ke)
    rhs = -apply_matrix(p.pattern, Ke, p.dirichlet(5.0, -3.0))[p.free]
    first = Factor(K)
    again = first.refactor(2.5 * K)  # same pattern, new values: phase 22 on the same solver
    assert again is first
    np.testing.assert_allclose(again.solve(rhs), Factor(2.5 * K).solve(rhs), rtol=1e-10, atol=1e-12)
    other = assemble_matrix(p.pattern, Ke)[:-3, :-3]  # another pattern: a fresh factorisation
    assert first.refactor(other) is not first


@pytest.mark.slow  # 16 s; `make test` (CI) runs it
def test_newton_with_amg_tangent_solves_reaches_pardisos_equilibrium(tiny_problem, monkeypatch):
    """Above AMG_MIN_DOFS Newton's tangent solves are AMG-preconditioned CG (the hierarchy of an
    earlier tangent reused while CG stays short); it must converge to the same state."""
    import fem_offline.fe.linsolve as ls
    from fem_offline.fe.solve import solve_case

    u_direct, direct = solve_case(tiny_problem, 2.5, 10.0)
    monkeypatch.setattr(ls, "AMG_MIN_DOFS", 0)
    u_amg, amg = solve_case(tiny_problem, 2.5, 10.0)
    assert amg.cg_iterations > direct.cg_iterations  # the AMG path ran
    assert amg.residual <= tiny_problem.scene.solver.rtol
    assert np.abs(u_amg - u_direct).max() < 1e-4 * np.abs(u_direct).max()


def test_single_precision_factors_solve_to_float32_accuracy_and_refactor(tiny_linear_problem):
    """float32 factors (Newton's preconditioner): a solve is accurate to float32's precision times the
    condition, far inside CG's 1e-2, and phase 22 keeps them float32 on the same handle."""
    p = tiny_linear_problem
    Ke = el.linear_stiffness(p.G, p.W, p.mu, p.lam)
    K = assemble_matrix(p.pattern, Ke)
    rhs = -apply_matrix(p.pattern, Ke, p.dirichlet(5.0, 4.0))[p.free]
    single, double = Factor(K, float32=True), Factor(K)
    x32, x64 = single.solve(rhs), double.solve(rhs)
    assert x32.dtype == np.float64
    rel = np.linalg.norm(K @ x32 - rhs) / np.linalg.norm(rhs)
    assert 1e-12 < rel < 1e-4  # float32 arithmetic, not float64's (which reaches ~1e-15)
    assert np.linalg.norm(K @ x64 - rhs) / np.linalg.norm(rhs) < 1e-12
    assert np.abs(x32 - x64).max() < 1e-4 * np.abs(x64).max()
    again = single.refactor(2.0 * K)
    assert again is single and again.float32
    np.testing.assert_allclose(again.solve(rhs), 0.5 * x64, rtol=0, atol=1e-4 * np.abs(x64).max())


def test_newton_with_single_precision_factors_reaches_the_double_precision_equilibrium(tiny_problem, monkeypatch):
    """The float32 preconditioner changes the path's work, not its answer: both meet solver.rtol and agree."""
    import fem_offline.fe.newton as nt
    from fem_offline.fe.solve import solve_case

    monkeypatch.setattr(nt, "SINGLE_FACTORS", False)
    u64, st64 = solve_case(tiny_problem, 2.5, -7.0)
    monkeypatch.setattr(nt, "SINGLE_FACTORS", True)
    u32, st32 = solve_case(tiny_problem, 2.5, -7.0)
    assert max(st64.residual, st32.residual) <= tiny_problem.scene.solver.rtol
    assert np.abs(u32 - u64).max() < 1e-6 * np.abs(u64).max()


def test_a_float32_correction_the_line_search_rejects_is_redone_with_float64_factors(tiny_problem, monkeypatch):
    """Where the correction through float32 factors lowers no energy (here: made an ascent direction; a
    1e4 stiffness contrast did it once in CI), Newton re-solves that iteration exactly with float64
    factors and keeps them, instead of failing the line search. From a perturbed equilibrium with the
    guide already in place, so every iteration must lower the energy (Armijo)."""
    from ..fe_helpers import newton_with_one_uphill_step

    p = tiny_problem
    u, g, stats, factor, spoiled = newton_with_one_uphill_step(p, monkeypatch, lambda f: f.float32)
    assert spoiled and not factor.float32  # the float64 factors are kept
    assert stats.residual <= p.scene.solver.rtol
    assert np.abs(u - g).max() < 1e-6 * np.abs(g).max()
