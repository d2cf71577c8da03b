"""studies/design_mc.py: the statistics on draws of known spread, the draws truncated to the box by ratios, and the
study end to end on the tiny design model (fresh FE per draw, saved and not solved again)."""

from types import SimpleNamespace

import numpy as np
import pytest

from contracts.materials import ratio_point
from studies.design_mc import compare, draw_thetas, report, run


def test_the_std_ratio_and_the_cover_of_draws_with_a_known_spread():
    """Draws u = a + xi J (xi ~ N(0, 1), J one direction per node): the model's std J gives ratio 1 and 95.4 %
    within 2 std (a 1-D normal's 2 sigma); half of it, ratio 0.5 and 68.3 % within 2 x (std / 2)."""
    rng = np.random.default_rng(0)
    answer, J = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    fresh = answer + rng.normal(size=(20000, 1, 1)) * J
    right = compare(fresh, answer, np.abs(J), 2.0)
    assert right["ratio"] == pytest.approx(1.0, abs=0.02) and right["covered"] == pytest.approx(0.954, abs=0.01)
    narrow = compare(fresh, answer, 0.5 * np.abs(J), 2.0)
    assert narrow["ratio"] == pytest.approx(0.5, abs=0.01) and narrow["covered"] == pytest.approx(0.683, abs=0.01)


def test_draws_are_the_normal_truncated_to_the_box_by_ratios():
    lo, hi = [-0.9, -0.7, -2.3, -1.2], [0.5, 0.5, 0.2, 1.1]
    info = SimpleNamespace(log_box=(lo, hi), tissues=["prostate", "adipose", "rectal_wall", "bladder"])
    centre = np.zeros(4)
    thetas, refused = draw_thetas(info, centre, np.full(4, 0.01), 200, seed=0)
    assert refused == 0  # far inside: nothing refused, and the ratios keep their spread (std of ln(E_i / E_j)
    # sigma sqrt 2); the common scale is dropped (the canonical point: theta minus its mean, sigma sqrt(3/4) each)
    np.testing.assert_allclose((thetas[:, 0] - thetas[:, 1]).std() / 0.01, np.sqrt(2), rtol=0.12)
    np.testing.assert_allclose(thetas.std(axis=0) / 0.01, np.sqrt(3 / 4), rtol=0.12)
    np.testing.assert_allclose(thetas.sum(axis=1), 0.0, atol=1e-12)
    corner = np.array(ratio_point([-0.9, -0.7, 0.2, 1.1], lo, hi, info.tissues))
    thetas, refused = draw_thetas(info, corner, np.full(4, 0.21), 200, seed=0)
    assert refused > 50  # at a corner about half the draws lie outside by ratios
    for t in thetas:  # each draw is answerable and at its canonical point
        np.testing.assert_allclose(ratio_point(t.tolist(), lo, hi, info.tissues), t, atol=1e-12)
        assert all(a - 1e-12 <= x <= b + 1e-12 for x, a, b in zip(t, lo, hi))


@pytest.mark.slow  # 8 fresh solves of the tiny scene
def test_the_study_compares_the_design_models_std_with_fresh_fe(design_model, tmp_path):
    kw = dict(n=8, seed=0, out=tmp_path, workers=1, points={"nominal": {}}, cases=((4.0, 2.0),))
    data = run(design_model, solve_missing=True, **kw)
    (row,) = data["rows"]
    assert row["solved"] == 8 and len(list(tmp_path.glob("*.npz"))) == 8
    for region in ("markers", "prostate_surface"):
        assert 0.6 < row[region]["ratio"] < 1.6  # 8 draws: a sample std is uncertain by about 27 %
        assert row[region]["covered"] > 0.6
    again = run(design_model, solve_missing=False, **kw)  # from the saved solves alone
    assert again["rows"] == data["rows"]
    assert "| nominal | 4 mm, 2 deg | 8 of 8 |" in report(data)
