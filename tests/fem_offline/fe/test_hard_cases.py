"""The patient box's hardest corner and the ratio invariance, with the element and the contact penalty of
fem_offline/scenes/patient_box.toml (studies/hard_cases.py): P2/P0 mean dilatation,
k scaled with the stiffest tissue's E."""

import numpy as np
import pytest

from fem_offline.fe.continuation import solve_path
from fem_offline.fe.problem import build_problem
from fem_offline.fe.sensitivity import sensitivities, stiffened
from fem_offline.scene import load_scene
from studies.hard_cases import GCI_POINTS, SCENE, at_factors, box_of, formulation, worst_volume

HARDEST = GCI_POINTS["hardest corner"]  # soft gland and fat, stiff wall and bladder
PATIENT_BOX = load_scene(SCENE)
CONTACT_PER_MM = PATIENT_BOX.guide.contact_stiffness_per_mm


def test_the_hardest_corner_is_a_corner_of_the_patient_box():
    box = box_of(PATIENT_BOX)
    assert PATIENT_BOX.solver.volumetric == "mean_dilatation" and CONTACT_PER_MM is not None
    assert all(HARDEST[t] in box[t] for t in box)


def _contact(scene, step_mm: float):
    return scene.model_copy(update={"effects": scene.effects.model_copy(update={"guide_contact": True}),
                                    "solver": scene.solver.model_copy(update={"max_step_mm": step_mm})})


@pytest.mark.slow
def test_the_hardest_corner_solves_to_the_full_push_without_a_collapsing_element(tiny_scene, tiny_mesh):
    """Taylor-Hood stops near 6.5 mm here with one adipose element at det F 0.03 (docs: Hard cases); P2/P0 solves
    all 10 mm with every tet keeping most of its volume."""
    scene = at_factors(formulation(_contact(tiny_scene, 0.5), "mean_dilatation", CONTACT_PER_MM), HARDEST)
    problem = build_problem(scene, tiny_mesh)
    (d, u, stats), = solve_path(problem, [10.0], 0.0)
    worst = worst_volume(problem, u)
    assert d == 10.0 and stats.penetration_mm <= scene.guide.contact_tol_mm
    assert worst["min_volume_ratio"] > 0.9 and worst["min_det_f"] > 0.4


@pytest.fixture(scope="module")
def scaled_contact(tiny_scene, tiny_mesh):
    """P2/P0, the tip in contact with the scaled penalty, 2 mm at beta = 10 deg in 1 mm steps."""
    scene = formulation(_contact(tiny_scene, 1.0), "mean_dilatation", CONTACT_PER_MM)
    problem = build_problem(scene, tiny_mesh)
    (d, u, _, state), = solve_path(problem, [2.0], 10.0, with_state=True)
    return scene, problem, problem.at_guide(d, 10.0, state.multipliers), state.u


def test_the_penalty_follows_the_stiffest_deforming_tissue(scaled_contact, tiny_mesh):
    """k = per_mm x the stiffest E of the tissues that deform: the wall at the nominal; with the wall x0.1, the
    bladder behind it (the fixed bones, stiffer still, do not count)."""
    scene, problem, _, _ = scaled_contact
    assert problem.contact.stiffness == pytest.approx(CONTACT_PER_MM * scene.tissues["rectal_wall"].youngs)
    softer = build_problem(at_factors(scene, {"rectal_wall": 0.1}), tiny_mesh)
    soft_tissues = [t.youngs for t in scene.tissues.values() if not t.bone]
    assert max(t.youngs for t in scene.tissues.values()) > max(soft_tissues)  # the bones are stiffer, and left out
    assert softer.contact.stiffness == pytest.approx(
        CONTACT_PER_MM * max(e for e in soft_tissues if e != scene.tissues["rectal_wall"].youngs))


@pytest.mark.slow
def test_a_soft_wall_before_a_stiff_gland_solves_to_the_full_push(tiny_scene, tiny_mesh):
    """The corner prostate x1.6, adipose x0.5, rectal wall x0.1, bladder x0.3: with k following the wall alone (10x
    softer), the multiplier updates stopped converging at 7.25-7.5 mm on the served mesh (docs: Hard cases); with k
    following the stiffest tissue it reaches 10 mm within the contact tolerance."""
    corner = {"prostate": 1.6, "adipose": 0.5, "rectal_wall": 0.1, "bladder": 0.3}
    scene = at_factors(formulation(_contact(tiny_scene, 0.5), "mean_dilatation", CONTACT_PER_MM), corner)
    problem = build_problem(scene, tiny_mesh)
    (d, u, stats), = solve_path(problem, [10.0], 0.0)
    assert d == 10.0 and stats.penetration_mm <= scene.guide.contact_tol_mm
    assert worst_volume(problem, u)["min_volume_ratio"] > 0.9


def test_every_stiffness_times_k_gives_the_same_u_with_the_tip_in_contact(scaled_contact, tiny_mesh):
    """u(3 E) = u(E) to 1e-6 of |u|: the penalty and its multipliers scale with the tissues."""
    scene, _, _, u = scaled_contact
    stiffer = build_problem(at_factors(scene, dict.fromkeys(("prostate", "adipose", "rectal_wall", "bladder"), 3.0)),
                            tiny_mesh)
    (_, u3, _), = solve_path(stiffer, [2.0], 10.0)
    assert np.abs(u3.ravel() - u).max() < 1e-6 * np.abs(u).max()


def test_the_sensitivities_sum_to_zero_with_the_tip_in_contact(scaled_contact):
    _, problem, loaded, u = scaled_contact
    sens = sensitivities(stiffened(problem), loaded, u)
    largest = max(np.abs(s).max() for s in sens.values())
    assert largest > 1e-3 * np.abs(u).max()
    assert np.abs(sum(sens.values())).max() < 1e-5 * largest


@pytest.mark.slow
def test_the_rectal_walls_sensitivity_is_the_central_difference_with_the_scaled_penalty(tiny_scene, tiny_mesh):
    """The wall's E (the stiffest tissue here) moves the penalty with it: S_wall against (u(E e^h) - u(E e^-h)) / 2h,
    h = 0.02, with the contact settled to 1e-5 mm (the default 5e-3 mm / h would swamp the quotient) and Newton to
    1e-9."""
    scene = formulation(_contact(tiny_scene, 1.0), "mean_dilatation", CONTACT_PER_MM)
    scene = scene.model_copy(update={"guide": scene.guide.model_copy(update={"contact_tol_mm": 1e-5}),
                                     "solver": scene.solver.model_copy(update={"rtol": 1e-9})})

    def solve(factor):
        problem = build_problem(at_factors(scene, {"rectal_wall": factor}), tiny_mesh)
        (d, u, _, state), = solve_path(problem, [2.0], 10.0, with_state=True)
        return problem, problem.at_guide(d, 10.0, state.multipliers), state.u

    problem, loaded, u = solve(1.0)
    s = sensitivities(stiffened(problem, ("rectal_wall",)), loaded, u)["rectal_wall"]
    h = 0.02
    fd = (solve(np.exp(h))[2] - solve(np.exp(-h))[2]).reshape(-1, 3) / (2 * h)
    assert np.abs(s - fd).max() < 0.01 * np.abs(fd).max()
