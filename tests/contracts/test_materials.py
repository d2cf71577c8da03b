"""Stiffness inputs (contracts/materials.py): the one std_percent conversion, the ratio judgement's point and its
refusal, and which models it applies to (contracts.model.judged_by_ratios)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from contracts.materials import OutsideBox, ratio_point, ratio_shift_interval, sigma_ln_e, youngs_from_shear_wave_kpa
from contracts.model import judged_by_ratios, read_manifest
from contracts.scene import PHANTOM_TISSUES, Scene, Tissue

DEFAULT = Path(__file__).resolve().parents[2] / "models" / "default"
TISSUES = ("prostate", "rectal_wall", "adipose", "bladder")
# the patient box of docs/materials.md, as ln(E / E_nominal)
LO = [math.log(r) for r in (0.4, 0.1, 0.5, 0.3)]
HI = [math.log(r) for r in (1.6, 1.2, 1.6, 3.0)]


def test_a_percentage_a_std_in_kpa_and_a_shear_wave_std_give_one_sigma():
    """p % of E is sigma = p / 100, the same as a std of p % x E in kPa; p % of v_s is 2 p / 100, which is the
    std of ln E that eq. 1 (E ~ v_s^2) gives a small relative error of v_s (a finite difference)."""
    youngs, v = 70.0, 4.4
    assert sigma_ln_e(std=21.0, value=100.0) == pytest.approx(0.21)
    assert sigma_ln_e(std=0.21 * youngs, value=youngs) == pytest.approx(sigma_ln_e(std=21.0, value=100.0))
    h = 1e-4
    e = [youngs_from_shear_wave_kpa(shear_wave_speed_m_s=v * (1 + s * h), density_kg_m3=1008.0, poisson=0.495)
         for s in (1, -1)]
    d_ln_e_d_rel_v = (math.log(e[0]) - math.log(e[1])) / (2 * h)
    assert sigma_ln_e(std=0.05 * v, value=v, shear_wave=True) == pytest.approx(0.05 * d_ln_e_d_rel_v, rel=1e-6)


@pytest.mark.parametrize("theta", [[0.0, 0.0, 0.0, 0.0], [-0.7, -1.5, 0.2, 0.9], [1.0, -0.5, 0.1, 1.7],
                                   [-0.9, -2.2, -0.6, -1.1]])
def test_the_ratio_point_is_in_the_box_has_thetas_ratios_and_ignores_a_common_scale(theta):
    """theta - c*: inside the box, the same differences theta_i - theta_j, the same point for theta + ln k, and of
    all such points in the box the nearest to theta = 0 (c* minimises |theta - c|^2 over the allowed c)."""
    point = np.array(ratio_point(theta, LO, HI, TISSUES))
    assert (np.array(LO) - 1e-12 <= point).all() and (point <= np.array(HI) + 1e-12).all()
    shift = np.asarray(theta) - point
    np.testing.assert_allclose(shift, shift[0], atol=1e-12)
    for k in (1e-3, 0.5, 7.0, 1e4):
        np.testing.assert_allclose(ratio_point([t + math.log(k) for t in theta], LO, HI, TISSUES), point, atol=1e-12)
    a, b = ratio_shift_interval(theta, LO, HI)
    for c in np.linspace(a, b, 41):
        assert np.sum(point**2) <= np.sum((np.asarray(theta) - c) ** 2) + 1e-12


def test_ratios_no_point_of_the_box_has_are_refused_naming_both_tissues_and_the_bound():
    """A prostate 3.2 x its nominal ratio to the adipose is the box's edge (1.6 / 0.5); just past it, OutsideBox names
    the prostate as the stiff one, the adipose as the soft one, and the ratio the box holds."""
    edge = [math.log(1.6 / 0.5), 0.0, 0.0, 0.0]  # rectal wall and bladder nominal leave room: only the adipose binds
    ratio_point(edge, LO, HI, TISSUES)
    with pytest.raises(OutsideBox) as info:
        ratio_point([edge[0] + 0.01, 0.0, 0.0, 0.0], LO, HI, TISSUES)
    assert (info.value.stiff, info.value.soft) == ("prostate", "adipose")
    assert "3.2 x" in str(info.value) and "up to x1.6" in str(info.value) and "down to x0.5" in str(info.value)


def _scene(**effects) -> Scene:
    """The phantom's tissues, the bones held fixed; `effects` changed without validation (fixed_bones = false is
    refused from a user, but the judgement must hold for any scene)."""
    scene = Scene(tissues={t: Tissue(youngs_kpa=10.0, bone=t in ("pubic_bone", "spine")) for t in PHANTOM_TISSUES})
    return scene.model_copy(update={"effects": scene.effects.model_copy(update=effects)})


@pytest.mark.parametrize("scene, inputs, expected", [
    (_scene(), TISSUES, True),  # every soft tissue an input; the bones held fixed move nothing
    (_scene(), TISSUES[:3], False),  # the bladder at its nominal E: E x k of the others is another patient
    (_scene(gravity=True), TISSUES, False),  # a body force scales with 1/E
    (_scene(fixed_bones=False), TISSUES, False),  # a free bone carries load
])
def test_a_model_is_judged_by_ratios_only_when_only_ratios_move_it(scene, inputs, expected):
    mesh_tissues = [*TISSUES, "pubic_bone", "spine"]
    assert judged_by_ratios(scene, tissues=mesh_tissues, inputs=list(inputs)) is expected


def test_a_manifest_from_before_the_judgement_reads_with_it_from_its_scene(tmp_path):
    """models/default's manifest has no by_ratios: read, it is judged by ratios (its four soft tissues are inputs)."""
    raw = json.loads((DEFAULT / "manifest.json").read_text())
    assert "by_ratios" not in raw["materials"]
    assert read_manifest(DEFAULT).materials.by_ratios is True
    raw["materials"]["by_ratios"] = False  # a manifest that states it keeps what it states
    (tmp_path / "manifest.json").write_text(json.dumps(raw))
    assert read_manifest(tmp_path).materials.by_ratios is False
