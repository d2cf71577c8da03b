"""Gravity: assembled only when switched on, with the total load -rho g V."""

import numpy as np
import pytest

from fem_offline.fe.problem import build_problem
from fem_offline.fe.solve import solve_case


def test_gravity_is_assembled_only_when_switched_on(tiny_scene, tiny_mesh, tiny_linear_problem):
    """Gravity on: zero guide displacement gives the sag, with total load -rho g V on the free z DOFs."""
    assert tiny_linear_problem.body_force is None
    effects = tiny_scene.effects.model_copy(update={"gravity": True, "geometric_nonlinearity": False})
    p = build_problem(tiny_scene.model_copy(update={"effects": effects}), tiny_mesh)
    volume = p.W.sum()
    assert p.body_force[2::3].sum() == pytest.approx(-1008 * 9.81 * 1e-6 * volume, rel=1e-9)
    u, _ = solve_case(p, 0.0, 0.0)
    assert u[:, 2].min() < -0.1 and np.abs(u[p.mesh.node_sets["bones"]]).max() == 0.0
