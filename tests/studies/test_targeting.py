"""The targeting study (studies/targeting.py) on the tiny material model: its scene solved afresh at random points
(small strain: one linear solve each), the estimate recovering the FE lesions, the plan checked on fresh FE."""

import numpy as np

from studies.targeting import draw_points, lesion_points, report, run


def test_points_stay_inside_the_envelope_and_lesions_inside_the_prostate(tiny_material_model):
    from service.model import Predictor, read_model_folder

    folder = read_model_folder(tiny_material_model)
    states = draw_points(folder.manifest, 500, seed=0)
    (d_lo, d_hi), (a_lo, a_hi) = folder.manifest.envelope.displacement_mm, folder.manifest.envelope.angle_deg
    assert d_lo <= states[:, 0].min() and states[:, 0].max() <= d_hi and a_lo <= states[:, 1].min() <= a_hi
    for i, m in enumerate(folder.manifest.materials.inputs):
        assert np.exp(states[:, 2 + i]).min() * m.nominal_youngs_kpa >= m.youngs_kpa_range[0] * (1 - 1e-9)
    lesions = lesion_points(folder, 5, seed=0)
    tet, _ = Predictor(folder).locator.locate(lesions)
    assert (folder.mesh.tissue[tet] == folder.manifest.mesh.tissues.index("prostate")).all()
    assert np.min(np.linalg.norm(lesions[:, None] - folder.nodes[None], axis=2)) > 1e-3  # not nodes


def test_the_study_solves_afresh_estimates_and_plans_and_resumes(tiny_material_model, tmp_path):
    """At 2 points: the estimate from 8 markers at 0.2 mm puts the lesions closer to the FE than "no deformation"
    does; the plan is checked on fresh FE at both poses, where the tiny model's surrogate is its FE to within 0.05 mm;
    a rerun with --solved-only reads the same files."""
    kw = dict(n=2, seed=0, n_lesions=2, draws=2, plan_points=1, out=tmp_path / "t")
    data = run(tiny_material_model, solve_missing=True, **kw)
    assert data["n_solved"] == 2 and len(data["plans"]) == 1
    rows = {r["configuration"]: r for r in data["rows"]}
    assert rows["0.2 mm, 8 markers"]["median_mm"] < data["baselines"]["no_deformation"]["median_mm"]
    plan = data["plans"][0]
    for key in ("planned", "naive"):  # the tiny model's surrogate is its FE, closely
        assert abs(plan[f"fe_{key}_miss_mm"] - plan[f"predicted_{key}_miss_mm"]) < 0.05
    again = run(tiny_material_model, solve_missing=False, **kw)
    assert again["n_solved"] == 2 and again["plans"] == data["plans"]
    assert "| 0.2 mm, 8 markers |" in report(data)
