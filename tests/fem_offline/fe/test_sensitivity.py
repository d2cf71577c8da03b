"""du/d ln E_i by one tangent solve (fem_offline/fe/sensitivity.py), against finite differences of fresh
solves, and the ratio invariance: with the guide prescribing displacements and gravity off, only the
ratios of the stiffnesses matter."""

import numpy as np
import pytest

from fem_offline.fe.continuation import solve_path
from fem_offline.fe.problem import build_problem
from fem_offline.fe.sensitivity import first_order, propagated_std, sensitivities, soft_tissues, stiffened

D_MM, BETA_DEG = 3.0, 10.0


def _scaled(scene, factors: dict[str, float]):
    tissues = {n: t.model_copy(update={"youngs_kpa": t.youngs * factors.get(n, 1.0), "shear_wave_speed_m_s": None})
               for n, t in scene.tissues.items()}
    return scene.model_copy(update={"tissues": tissues})


def _equilibrium(problem, d_mm=D_MM):
    (d, u, _, state), = solve_path(problem, [d_mm], BETA_DEG, with_state=True)
    return problem.at_guide(d, BETA_DEG, state.multipliers), state.u


def _variant(scene, **solver_effects):
    effects = {k: v for k, v in solver_effects.items() if k in type(scene.effects).model_fields}
    solver = {k: v for k, v in solver_effects.items() if k in type(scene.solver).model_fields}
    return scene.model_copy(update={"effects": scene.effects.model_copy(update=effects),
                                    "solver": scene.solver.model_copy(update=solver)})


@pytest.fixture(scope="module")
def glued(tiny_scene, tiny_mesh):
    problem = build_problem(tiny_scene, tiny_mesh)
    loaded, u = _equilibrium(problem)
    return problem, u, sensitivities(stiffened(problem), loaded, u)


def test_the_soft_tissues_are_the_assembled_ones(glued):
    problem, _, sens = glued
    assert set(soft_tissues(problem)) == {"adipose", "rectal_wall", "prostate", "bladder"}  # the bones are held
    assert set(sens) == set(soft_tissues(problem))


def test_scaling_every_stiffness_by_one_factor_leaves_u_unchanged(tiny_scene, tiny_mesh, glued):
    """Nonlinear, glued guide: u(c E) = u(E) for c = 3, to the solver's tolerance."""
    _, u, _ = glued
    stiffer = build_problem(_scaled(tiny_scene, dict.fromkeys(tiny_scene.tissues, 3.0)), tiny_mesh)
    _, u3 = _equilibrium(stiffer)
    assert np.abs(u3 - u).max() < 1e-6 * np.abs(u).max()


def test_the_sensitivities_sum_to_zero(glued):
    """d u / d ln c for E -> c E is sum_i S_i, and u does not depend on c."""
    _, u, sens = glued
    total = sum(sens.values())
    largest = max(np.abs(s).max() for s in sens.values())
    assert largest > 1e-3 * np.abs(u).max()  # each tissue does move the answer
    assert np.abs(total).max() < 1e-6 * largest


@pytest.mark.parametrize("tissue", ["prostate", "adipose", "rectal_wall", "bladder"])
def test_each_sensitivity_is_the_central_difference_of_fresh_solves(tiny_scene, tiny_mesh, glued, tissue):
    """(u(E_i e^h) - u(E_i e^-h)) / 2h, h = 0.02: O(h^2) from S_i; the first-order answer at +-25 % is within
    its second-order remainder, small against the change itself."""
    _, u, sens = glued
    h = 0.02
    plus = _equilibrium(build_problem(_scaled(tiny_scene, {tissue: np.exp(h)}), tiny_mesh))[1].reshape(-1, 3)
    minus = _equilibrium(build_problem(_scaled(tiny_scene, {tissue: np.exp(-h)}), tiny_mesh))[1].reshape(-1, 3)
    fd = (plus - minus) / (2 * h)
    assert np.abs(sens[tissue] - fd).max() < 2e-3 * np.abs(fd).max() + 1e-9


@pytest.mark.slow
def test_with_the_tip_in_contact_and_taylor_hood_the_sensitivity_is_the_central_difference(tiny_scene, tiny_mesh):
    """The default's physics (frictionless contact, P2/P1) on the tiny mesh, for the prostate, at 1.5 mm, with the
    contact settled to 1e-5 mm and Newton to 1e-9: at the default 5e-3 mm the quotient's noise (tol / h) is as
    large as the penalty's compliance that the sensitivity leaves out (fe/sensitivity.py, _constrained)."""
    scene = _variant(tiny_scene, guide_contact=True, volumetric="taylor_hood", rtol=1e-9)
    scene = scene.model_copy(update={"guide": scene.guide.model_copy(update={"contact_tol_mm": 1e-5})})
    problem = build_problem(scene, tiny_mesh)
    loaded, u = _equilibrium(problem, 1.5)
    s = sensitivities(stiffened(problem, ("prostate",)), loaded, u)["prostate"]
    h = 0.02
    plus = _equilibrium(build_problem(_scaled(scene, {"prostate": np.exp(h)}), tiny_mesh), 1.5)[1].reshape(-1, 3)
    minus = _equilibrium(build_problem(_scaled(scene, {"prostate": np.exp(-h)}), tiny_mesh), 1.5)[1].reshape(-1, 3)
    fd = (plus - minus) / (2 * h)
    assert np.abs(s - fd).max() < 0.01 * np.abs(fd).max()


def test_first_order_answer_and_propagated_std(glued):
    _, u, sens = glued
    u = u.reshape(-1, 3)
    moved = first_order(u, sens, {"prostate": np.log(1.25)})
    np.testing.assert_allclose(moved - u, sens["prostate"] * np.log(1.25))
    std = propagated_std(sens, {"prostate": 0.1, "adipose": 0.2})
    np.testing.assert_allclose(std, np.sqrt((0.1 * sens["prostate"]) ** 2 + (0.2 * sens["adipose"]) ** 2))
