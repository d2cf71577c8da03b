"""The guide: push direction in the tilt plane, and the rounded-tip field it prescribes on the patch."""

import numpy as np
import pytest

from fem_offline.fe.guide import direction
from fem_offline.scene import Guide
from fem_offline.fe.solve import solve_case


def test_guide_direction_rotates_in_the_tilt_plane():
    a = direction(Guide(), 10.0)
    assert np.linalg.norm(a) == pytest.approx(1.0)
    assert a[2] == pytest.approx(0.0)
    assert np.degrees(np.arctan2(-a[0], a[1])) == pytest.approx(10.0)


def test_prescribed_patch_follows_the_rounded_tip(tiny_problem):
    """u = d w(r) a(beta) on the patch; w = 1 at the tip, -> 0 at the rim."""
    u, _ = solve_case(tiny_problem, 1.0, -4.0)
    patch = tiny_problem.guide_dofs[:, 0] // 3
    expected = tiny_problem.guide_weight[:, None] * direction(tiny_problem.scene.guide, -4.0)
    np.testing.assert_allclose(u[patch], expected, atol=1e-12)
