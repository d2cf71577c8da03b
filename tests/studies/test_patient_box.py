"""The share of patients a stiffness box holds (studies/patient_box.py), judged by ratios as the service does."""

import math

import numpy as np
import pytest

from contracts.materials import OutsideBox, ratio_point
from fem_offline.scene import load_scene
from studies.patient_box import report, run, shares

from ..conftest import SCENES

BOX = load_scene(SCENES / "patient_box.toml")


def _population(**over):
    base = {t: (BOX.tissues[t].youngs, 0.0, "nominal") for t in BOX.materials}
    return {"p": base | over}


def test_the_study_judges_a_draw_as_the_service_does():
    """Each draw's verdict by ratios is whether contracts.materials.ratio_point finds it a point of the box."""
    tissues = list(BOX.materials)
    lo, hi = (np.log([BOX.materials[t].youngs_kpa_range[j] / BOX.tissues[t].youngs for t in tissues]) for j in (0, 1))
    theta = np.random.default_rng(3).normal(size=(400, 4)) * 0.8
    for row in theta:
        try:
            ratio_point(row.tolist(), lo.tolist(), hi.tolist(), tissues)
            inside = True
        except OutsideBox:
            inside = False
        assert shares(row[None], lo, hi)[0] == float(inside)


def test_every_patient_at_a_common_scale_of_the_nominal_is_inside_by_ratios_and_few_by_absolute_e():
    """All four tissues at 0.3 x nominal (a soft-reading scanner): the same ratios as nominal, so inside by ratios,
    and outside by absolute E (the adipose's range ends at x0.5)."""
    soft = {t: (0.3 * BOX.tissues[t].youngs, 0.0, "") for t in BOX.materials}
    row = run(BOX, n=10, seed=0, populations={"soft": soft})["populations"]["soft"]
    assert row["by_ratios"] == 1.0 and row["by_absolute_e"] == 0.0


def test_a_prostate_beyond_every_ratio_the_box_holds_is_never_inside():
    """A prostate at 40 x nominal against nominal others: over x1.6 / x0.5 against the adipose at any scale."""
    row = run(BOX, n=1000, seed=0, populations=_population(prostate=(40 * 65.89, 0.1, "")))["populations"]["p"]
    assert row["by_ratios"] == 0.0


def test_ratios_hold_every_patient_absolute_e_holds_and_the_report_says_both():
    data = run(BOX, n=20_000, seed=1)
    for row in data["populations"].values():
        assert row["by_ratios"] >= row["by_absolute_e"]
    assert data["box_ratio_to_nominal"]["bladder"] == pytest.approx([0.3, 3.0])
    assert math.isclose(data["box_ratio_to_nominal"]["prostate"][0], 0.4, rel_tol=1e-4)
    text = report(data)
    assert "| benign gland |" in text and "inside by ratios" in text
