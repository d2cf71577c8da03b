"""One case through either model: zero load, the small-load linear limit, and where the models part."""

import numpy as np
import pytest

from fem_offline.fe.solve import solve_case


@pytest.mark.parametrize("problem", ["tiny_problem", "tiny_linear_problem"])
def test_zero_guide_displacement_gives_exactly_zero(problem, request):
    u, stats = solve_case(request.getfixturevalue(problem), 0.0, 7.0)
    assert np.all(u == 0.0)


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
