"""Path continuation: the hard corner of the sweep converges without inversion; failure is loud."""

import numpy as np
import pytest

from fem_offline.fe.newton import ConvergenceError, residual
from fem_offline.fe.problem import build_problem
from fem_offline.fe.solve import solve_case


def test_hard_corner_converges_without_inversion(corner_path, tiny_problem):
    """10 mm at beta = 10 deg: independent re-check of equilibrium and det F > 0 at every quadrature point."""
    d, u, stats = corner_path[-1]
    assert d == 10.0
    r, min_j = residual(tiny_problem, u.ravel())[:2]
    reactions = np.linalg.norm(np.delete(r, tiny_problem.free))
    assert np.linalg.norm(r[tiny_problem.free]) <= tiny_problem.scene.solver.rtol * reactions
    assert min_j > 0.3 and stats.min_det_f == pytest.approx(min_j)
    np.testing.assert_allclose(u.ravel()[tiny_problem.guide_dofs.ravel()],
                               tiny_problem.dirichlet(10.0, 10.0)[tiny_problem.guide_dofs.ravel()])


def test_failure_is_loud(tiny_scene, tiny_mesh):
    """A push far past what the mesh can take in one step, with no step halving, raises instead of returning."""
    solver = tiny_scene.solver.model_copy(update={"max_halvings": 0, "max_step_mm": 40.0, "max_iterations": 3})
    scene = tiny_scene.model_copy(update={"solver": solver})
    with pytest.raises(ConvergenceError):
        solve_case(build_problem(scene, tiny_mesh), 40.0, 10.0)
