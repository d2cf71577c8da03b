"""The guide tip in frictionless contact with the wall (fem_offline/fe/contact.py, effects.guide_contact)."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from skfem import MeshTet

from fem_offline.fe import contact as ct
from fem_offline.fe.assembly import build_pattern
from fem_offline.fe.continuation import advance, PathState, solve_path
from fem_offline.fe.materials import lame_kpa
from fem_offline.geometry.mirror import mirror_map, reflect
from fem_offline.fe.newton import Stats, residual
from fem_offline.fe.problem import Problem, build_problem
from fem_offline.scene import load_scene
from fem_offline.fe.solve import solve_case

from ..conftest import SCENES
from ..fe_helpers import p2_data


def _with_contact(scene, **guide):
    return scene.model_copy(update={"effects": scene.effects.model_copy(update={"guide_contact": True}),
                                    "guide": scene.guide.model_copy(update=guide)})


@pytest.fixture(scope="module")
def contact_problem(tiny_scene, tiny_mesh):
    return build_problem(_with_contact(tiny_scene), tiny_mesh)


@pytest.fixture(scope="module")
def contact_path(contact_problem):
    """beta = 5 deg, 1 and 2 mm in 1 mm steps."""
    p = replace(contact_problem, scene=contact_problem.scene.model_copy(
        update={"solver": contact_problem.scene.solver.model_copy(update={"max_step_mm": 1.0})}))
    return p, list(solve_path(p, [1.0, 2.0], 5.0, with_state=True))


def test_no_glued_patch_and_the_tip_touches_the_wall_at_rest(contact_problem):
    p = contact_problem
    assert p.guide_dofs.size == 0 and not p.dirichlet(10.0, 5.0).any()
    assert p.contact is not None and p.contact.shape[0] > 0
    touch = ct.evaluate(p.contact, np.zeros(p.n_dofs), p.at_guide(0.0, 0.0).contact_load)
    # the sphere is tangent to the lumen at the tip: nothing penetrates at rest, its nearest point is on it
    assert touch.penetration.max() <= 1e-9
    assert -touch.penetration.max() < 1.0  # a quadrature point within 1 mm of touching
    assert not touch.pressure.any() and touch.energy == 0.0
    ev = residual(p.at_guide(0.0, 0.0), np.zeros(p.n_dofs))
    assert np.abs(ev.r[p.free]).max() == 0.0  # rest is exactly in equilibrium


def test_force_is_the_energy_gradient_and_the_hessian_its_derivative(contact_problem):
    """Central differences of Pi_c and of the force, along a random direction, with multipliers."""
    p = contact_problem
    rng = np.random.default_rng(3)
    load = p.at_guide(1.5, 5.0).contact_load
    lam = np.where(rng.random(p.contact.shape) < 0.3, 20 * rng.random(p.contact.shape), 0.0)
    load = ct.Load(load.centre, lam)
    u = np.zeros(p.n_dofs)
    u[p.contact.edofs] = 0.05 * rng.standard_normal(p.contact.edofs.shape)
    v = np.zeros(p.n_dofs)
    v[p.contact.edofs] = rng.standard_normal(p.contact.edofs.shape)
    h = 1e-6
    st = ct.evaluate(p.contact, u, load)
    assert (st.pressure > 0).sum() > 10  # the check covers points in contact
    f = ct.scatter(p.contact, st.force, p.n_dofs)
    fd = (ct.evaluate(p.contact, u + h * v, load).energy - ct.evaluate(p.contact, u - h * v, load).energy) / (2 * h)
    assert abs(f @ v - fd) <= 1e-6 * abs(fd)
    K = ct.stiffness(p.contact, st, curvature=True)
    Kv = ct.scatter(p.contact, np.einsum("faibk,fbk->fai", K, v[p.contact.edofs].reshape(-1, 10, 3)), p.n_dofs)
    df = (ct.scatter(p.contact, ct.evaluate(p.contact, u + h * v, load).force, p.n_dofs)
          - ct.scatter(p.contact, ct.evaluate(p.contact, u - h * v, load).force, p.n_dofs)) / (2 * h)
    assert np.abs(Kv - df).max() <= 1e-4 * np.abs(df).max()


def test_frictionless_flat_punch_gives_uniaxial_stress_exactly():
    """A rigid plane (a sphere of radius 1e6 mm) pushes the top of a unit cube by delta; the bottom
    slides on u_z = 0, the planes x = 0 and y = 0 are symmetry planes. Exact linear solution:
    u = (nu delta x, nu delta y, -delta z), which P2 reproduces; the contact force is E delta A."""
    E, nu, delta, tol = 10.0, 0.3, 0.1, 1e-6
    mesh = MeshTet.init_tensor(*(np.linspace(0, 1, 3),) * 3)
    nodes, tets, G, W, basis = p2_data(mesh)
    n = len(nodes)
    fixed = np.concatenate([3 * np.flatnonzero(np.abs(nodes[:, i]) < 1e-12) + i for i in range(3)])
    free = np.setdiff1d(np.arange(3 * n), fixed)
    mu, lam = lame_kpa(E, nu)
    top = mesh.facets_satisfying(lambda x: x[2] > 1 - 1e-12, boundaries_only=True)
    R = 1e6  # its sag over the face, 1.25e-7 mm, is below tol
    active = np.ones(len(tets), bool)
    surface = ct.facet_surface(mesh, top, tets, active, rest_centre=np.array([0.5, 0.5, 1.0 + R]), radius_mm=R,
                               stiffness=1e3, tol_mm=tol)
    scene = _with_contact(load_scene(SCENES / "tiny.toml"), axis=(0.0, 0.0, -1.0), tilt_normal=(1.0, 0.0, 0.0))
    scene = scene.model_copy(update={"effects": scene.effects.model_copy(update={"geometric_nonlinearity": False})})
    p = Problem(scene, SimpleNamespace(nodes=nodes), G, W, np.full(len(tets), mu), np.full(len(tets), lam),
                build_pattern(tets, n, free), fixed, np.zeros((0, 3), int), np.zeros(0), None, active, surface)
    state, stats = advance(p, PathState(np.zeros(3 * n)), delta, 0.0, Stats())
    p = p.at_guide(delta, 0.0, state.multipliers)
    u = state.u.reshape(-1, 3)
    exact = np.column_stack([nu * delta * nodes[:, 0], nu * delta * nodes[:, 1], -delta * nodes[:, 2]])
    assert stats.penetration_mm <= tol and stats.contact_updates >= 1
    np.testing.assert_allclose(u, exact, rtol=0, atol=2 * tol)
    touch = ct.evaluate(surface, state.u, p.contact_load)
    np.testing.assert_allclose(ct.resultant(surface, touch), [0, 0, E * delta], rtol=1e-4, atol=1e-6)


def test_path_converges_without_penetration_or_inversion(contact_path):
    p, steps = contact_path
    tol = p.scene.guide.contact_tol_mm
    forces = []
    for d, u, stats, state in steps:
        assert stats.penetration_mm <= tol and stats.min_det_f > 0
        load = p.at_guide(d, 5.0, state.multipliers).contact_load
        touch = ct.evaluate(p.contact, u.ravel(), load)
        assert touch.penetration.max() <= tol
        forces.append(ct.resultant(p.contact, touch))
        # equilibrium: the wall's push on the tip is what the bones and the table hold
        ev = residual(replace(p, contact_load=load), u.ravel())
        held = np.delete(ev.r, p.free).reshape(-1)  # reactions on constrained DOFs
        reaction = np.bincount(np.delete(np.arange(p.n_dofs), p.free) % 3, weights=held, minlength=3)
        np.testing.assert_allclose(reaction, forces[-1], rtol=1e-3, atol=1e-6 * np.linalg.norm(forces[-1]))
    push = [f @ p.scene.guide.direction(5.0) for f in forces]
    assert all(b < a < 0 for a, b in zip(push, push[1:]))  # against the push, growing with d


def test_mirror_symmetry_with_contact(contact_problem):
    """u(-beta) = S u(beta) on the mirror-symmetric phantom, to the solver's tolerance."""
    plus, _ = solve_case(contact_problem, 0.5, 8.0, step_mm=0.5)
    minus, _ = solve_case(contact_problem, 0.5, -8.0, step_mm=0.5)
    image = mirror_map(contact_problem.mesh)
    np.testing.assert_allclose(minus, reflect(plus, image), rtol=0, atol=1e-4 * np.abs(plus).max())


def test_linear_model_with_contact_is_solved_not_superposed(tiny_scene, tiny_mesh):
    """Small strain + contact is not linear in d: u(2 d) != 2 u(d), unlike the glued linear model."""
    scene = _with_contact(tiny_scene)
    scene = scene.model_copy(update={"effects": scene.effects.model_copy(update={"geometric_nonlinearity": False})})
    p = build_problem(scene, tiny_mesh)
    assert not p.superposable
    one, s1 = solve_case(p, 0.5, 0.0, step_mm=0.5)
    two, s2 = solve_case(p, 1.0, 0.0, step_mm=0.5)
    assert s1.penetration_mm <= scene.guide.contact_tol_mm and s2.iterations > 1
    assert np.abs(two - 2 * one).max() > 0.01 * np.abs(two).max()


def test_scene_hash_is_unchanged_by_the_contact_fields_left_at_their_defaults():
    """A scene that leaves the new fields at their defaults keeps the hash its sweeps and models carry:
    the glued default scene's, as recorded in the glued models/default (2026-11-23, before contact; that scene
    is grid_study_base.toml under the name "default")."""
    scene = load_scene(SCENES / "grid_study_base.toml").model_copy(update={"name": "default"})
    glued = scene.model_copy(update={"effects": scene.effects.model_copy(update={"guide_contact": False})})
    assert glued.sha256() == "b657e44c15571315239bcc3b711a9f91070b8b821fe7cb572d8d43b36a9f1e36"
    assert scene.sha256() != glued.sha256()
    assert _with_contact(glued, tip_radius_mm=5.0).sha256() != scene.sha256()


def test_contact_needs_a_rectal_wall(tiny_mesh):
    names = tuple("wall" if n == "rectal_wall" else n for n in tiny_mesh.tissue_names)
    with pytest.raises(ValueError, match="rectal_wall"):
        ct.lumen_faces(replace(tiny_mesh, tissue_names=names))
