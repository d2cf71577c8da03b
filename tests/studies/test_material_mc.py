"""Monte Carlo over fresh FE solves against first-order propagation of the material std (studies/material_mc.py),
on the tiny material sweep (small strain: each draw is one linear solve)."""

import numpy as np
import pytest

from studies.material_mc import draws, report, run

from ..conftest import TINY_MATERIALS, tiny_material_scene


def test_draws_have_the_services_sigma_and_stay_inside_the_ranges():
    """The study draws each ln E with the std the service feeds the graph for the scene's std_percent (one
    conversion, contracts.materials.sigma_ln_e: 20 % is sigma 0.20), and for a request stating that percentage."""
    from service.materials import material_vectors, materials_request_model
    from training.materials import materials_info

    scene = tiny_material_scene()
    tissues, theta, sigma = draws(scene, 4000, seed=1)
    assert tissues == tuple(TINY_MATERIALS)
    info = materials_info(scene)
    np.testing.assert_allclose(sigma, material_vectors(info, None)[1], rtol=1e-6)
    stated = materials_request_model(info).model_validate({t: {"std_percent": 20.0} for t in tissues})
    np.testing.assert_allclose(sigma, material_vectors(info, stated)[1], rtol=1e-6)
    np.testing.assert_allclose(sigma, 0.20)
    for i, t in enumerate(tissues):
        lo, hi = (np.log(e / scene.tissues[t].youngs) for e in TINY_MATERIALS[t]["youngs_kpa_range"])
        assert lo - 1e-12 <= theta[:, i].min() and theta[:, i].max() <= hi + 1e-12
    # clipping narrows the spread; the draws are independent
    assert (theta.std(axis=0) < sigma).all() and np.abs(np.corrcoef(theta.T) - np.eye(4)).max() < 0.06


def test_first_order_spread_matches_fresh_solves_and_the_model_carries_it(tiny_material_sweep, tiny_material_model,
                                                                          tmp_path):
    """At 5 mm / 2 deg, 40 draws: the std of the fresh solves and sqrt(sum sigma_i^2 S_i^2) agree at their largest
    within the sample's own uncertainty (1 / sqrt(78) = 11 %), the served model's displacement_std agrees with the
    first-order one (its surrogate error on S_i), and a rerun solves nothing again."""
    scene = tiny_material_scene()
    data = run(scene, tiny_material_sweep, (5.0, 2.0), 40, 0, tmp_path / "mc", tiny_material_model)
    assert data["n_solved"] == 40 and not data["unsolved"]
    for name, r in data["regions"].items():
        assert r["mc_std_max_mm"] > 0
        assert abs(r["mc_std_max_mm"] / r["first_order_std_max_mm"] - 1) < 2.5 * data["sampling_uncertainty"], name
        assert r["model_std_max_mm"] == pytest.approx(r["first_order_std_max_mm"], rel=0.05), name
    files = sorted((tmp_path / "mc").glob("draw_*.npz"))
    assert len(files) == 40
    stamps = [f.stat().st_mtime_ns for f in files]
    again = run(scene, tiny_material_sweep, (5.0, 2.0), 40, 0, tmp_path / "mc", None)
    assert [f.stat().st_mtime_ns for f in files] == stamps
    assert again["regions"]["markers"]["mc_std_max_mm"] == data["regions"]["markers"]["mc_std_max_mm"]
    assert "| markers |" in report(data)


def test_a_position_off_the_grid_is_refused(tiny_material_sweep, tmp_path):
    with pytest.raises(ValueError, match="--case 5.5/0"):
        run(tiny_material_scene(), tiny_material_sweep, (5.5, 0.0), 4, 0, tmp_path, None)
