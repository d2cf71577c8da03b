"""Phantom solves: zero load, mirror symmetry, small-load linear limit, hard corners, loud failure."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from fem_offline.newton import ConvergenceError, residual
from fem_offline.problem import build_problem
from fem_offline.solve import solve_case


def _mirror_map(nodes):
    """Index of each node's mirror image (x -> -x)."""
    dist, idx = cKDTree(nodes).query(nodes * [-1, 1, 1])
    assert dist.max() < 1e-9
    return idx


@pytest.mark.parametrize("problem", ["tiny_problem", "tiny_linear_problem"])
def test_zero_guide_displacement_gives_exactly_zero(problem, request):
    u, stats = solve_case(request.getfixturevalue(problem), 0.0, 7.0)
    assert np.all(u == 0.0)


def test_prescribed_patch_follows_the_rounded_tip(tiny_problem):
    """u = d w(r) a(beta) on the patch; w = 1 at the tip, -> 0 at the rim."""
    u, _ = solve_case(tiny_problem, 1.0, -4.0)
    patch = tiny_problem.guide_dofs[:, 0] // 3
    expected = tiny_problem.guide_weight[:, None] * tiny_problem.scene.guide.direction(-4.0)
    np.testing.assert_allclose(u[patch], expected, atol=1e-12)


@pytest.mark.parametrize("problem", ["tiny_linear_problem", "tiny_problem"])
def test_mirror_symmetry_beta_to_minus_beta(problem, request):
    """On the mirror-symmetric phantom, u(X; d, -b) = S u(S X; d, b), S = diag(-1, 1, 1)."""
    p = request.getfixturevalue(problem)
    plus, _ = solve_case(p, 2.0, 10.0)
    minus, _ = solve_case(p, 2.0, -10.0)
    image = _mirror_map(p.mesh.nodes)
    np.testing.assert_allclose(minus, plus[image] * [-1, 1, 1], atol=1e-6 * np.abs(plus).max())


def test_nonlinear_tends_to_linear_as_load_vanishes(tiny_problem, tiny_linear_problem):
    """||u_nl - u_lin|| / ||u_lin|| = O(d): small at 0.01 mm and halving with d."""
    rel = []
    for d in (0.02, 0.01):
        nl, _ = solve_case(tiny_problem, d, 5.0)
        lin, _ = solve_case(tiny_linear_problem, d, 5.0)
        rel.append(np.linalg.norm(nl - lin) / np.linalg.norm(lin))
    assert rel[1] < 1e-3
    assert rel[1] / rel[0] == pytest.approx(0.5, abs=0.05)


def test_nonlinear_differs_measurably_at_10mm(corner_path, tiny_linear_problem):
    d, u_nl, _ = corner_path[-1]
    u_lin, _ = solve_case(tiny_linear_problem, d, 10.0)
    prostate = tiny_linear_problem.mesh.node_sets["prostate_surface"]
    diff = np.linalg.norm(u_nl[prostate] - u_lin[prostate], axis=1)
    assert diff.max() > 0.1  # mm; the surrogate must learn the nonlinear field


def test_hard_corner_converges_without_inversion(corner_path, tiny_problem):
    """10 mm at beta = 10 deg: independent re-check of equilibrium and det F > 0 at every quadrature point."""
    d, u, stats = corner_path[-1]
    assert d == 10.0
    r, min_j = residual(tiny_problem, u.ravel())[:2]
    reactions = np.linalg.norm(np.delete(r, tiny_problem.free))
    assert np.linalg.norm(r[tiny_problem.free]) <= tiny_problem.scene.solver.rtol * reactions
    assert min_j > 0.3 and stats.min_det_f == pytest.approx(min_j)
    np.testing.assert_allclose(u.ravel()[tiny_problem.guide_dofs.ravel()], tiny_problem.dirichlet(10.0, 10.0)[tiny_problem.guide_dofs.ravel()])


def test_failure_is_loud(tiny_scene, tiny_mesh):
    """A push far past what the mesh can take in one step, with no step halving, raises instead of returning."""
    scene = tiny_scene.model_copy(update={"solver": tiny_scene.solver.model_copy(update={"max_halvings": 0, "max_step_mm": 40.0, "max_iterations": 3})})
    with pytest.raises(ConvergenceError):
        solve_case(build_problem(scene, tiny_mesh), 40.0, 10.0)


def test_gravity_is_assembled_only_when_switched_on(tiny_scene, tiny_mesh, tiny_linear_problem):
    """Gravity on: zero guide displacement gives the sag, with total load -rho g V on the free z DOFs."""
    assert tiny_linear_problem.body_force is None
    effects = tiny_scene.effects.model_copy(update={"gravity": True, "geometric_nonlinearity": False})
    p = build_problem(tiny_scene.model_copy(update={"effects": effects}), tiny_mesh)
    volume = p.W.sum()
    assert p.body_force[2::3].sum() == pytest.approx(-1008 * 9.81 * 1e-6 * volume, rel=1e-9)
    u, _ = solve_case(p, 0.0, 0.0)
    assert u[:, 2].min() < -0.1 and np.abs(u[p.mesh.node_sets["bones"]]).max() == 0.0


def test_table_constraint_only_when_switched_on(tiny_scene, tiny_mesh, tiny_problem):
    """Table on: u_z = 0 on the bottom face is a constraint; off: those DOFs are free. Bones are never assembled."""
    table_z = 3 * tiny_mesh.node_sets["table"] + 2
    assert np.isin(table_z, tiny_problem.fixed_dofs).all()
    effects = tiny_scene.effects.model_copy(update={"table": False})
    p = build_problem(tiny_scene.model_copy(update={"effects": effects}), tiny_mesh)
    bare = np.setdiff1d(table_z, 3 * tiny_mesh.node_sets["bones"] + 2)
    assert bare.size and not np.isin(bare, p.fixed_dofs).any()
    bone_ids = [tiny_mesh.tissue_names.index(n) for n in ("pubic_bone", "spine")]
    soft = (~np.isin(tiny_mesh.tissue, bone_ids)).sum()
    assert 0.95 * soft <= len(p.G) <= soft  # bone tets (all nodes fixed) are never assembled
