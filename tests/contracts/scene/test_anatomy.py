"""The phantom's anatomy: clearances as the closed forms give them, variants that span the issue's range,
label maps that hold each variant's anatomy, and a clear error for a phantom that is not anatomy."""

import numpy as np
import pytest

from contracts.scene import Phantom, SceneError, anatomy, parse_scene
from fem_offline.scene import load_scene
from studies.phantom_labelmap import LABELS, LUMEN, voxelise

from ...conftest import SCENES

VARIANTS = ("small", "medium", "large")


@pytest.fixture(scope="module")
def variants():
    return {v: load_scene(SCENES / "anatomy" / f"{v}.toml") for v in VARIANTS}


def test_default_clearances_are_the_closed_forms():
    """Prostate back y = -10 against the wall's front -9 and the lumen -14;
    bladder |(0, 4) - (0, -21)| = 25 = 13 + 12."""
    c = anatomy.clearances_mm(Phantom())
    assert c["prostate-lumen"] == pytest.approx(4.0, abs=1e-9)
    assert c["bladder-lumen"] == pytest.approx(25.0 - 7.0 - 13.0)
    assert c["rectal_wall-spine"] == pytest.approx(36.0 - 33.0)
    assert c["prostate-spine"] == pytest.approx(36.0 - 10.0)
    assert c["bladder-pubic_bone"] == pytest.approx(np.hypot(26.0, 20.0) - 6.0 - 13.0)


@pytest.mark.parametrize("variant", VARIANTS)
def test_sampled_clearances_are_within_a_hundredth_of_a_millimetre(variants, variant):
    """The prostate's surface is sampled; sampling it 16 times more densely moves no clearance by 0.01 mm."""
    ph = variants[variant].phantom
    coarse = anatomy.clearances_mm(ph)
    fine = anatomy.ellipsoid_surface(ph.prostate_center_mm, ph.prostate_semi_axes_mm,
                                     tuple(4 * n for n in anatomy.SURFACE_STEPS))
    exact = {"prostate-bladder": anatomy.sd_sphere(fine, ph.bladder_center_mm, ph.bladder_radius_mm).min(),
             "prostate-pubic_bone": anatomy.sd_x_bar(fine, ph.pubic_center_mm, ph.pubic_radius_mm,
                                                     ph.pubic_length_mm).min(),
             "prostate-lumen": anatomy.sd_z_cylinder(fine, ph.rectum_center_xy_mm, ph.rectum_inner_radius_mm).min()}
    for pair, value in exact.items():
        assert coarse[pair] == pytest.approx(value, abs=0.01), pair


def test_variants_span_the_issues_sizes_walls_and_offsets(variants):
    """30-60 mm prostates, 3-7 mm rectal walls, one prostate off the guide's axis; each tip on its lumen surface."""
    rows = {v: anatomy.describe(s.phantom) for v, s in variants.items()}
    assert [rows[v]["prostate_length_mm"] for v in VARIANTS] == [30.0, 45.0, 60.0]
    assert [rows[v]["rectal_wall_mm"] for v in VARIANTS] == [3.0, 5.0, 7.0]
    assert rows["large"]["prostate_offset_mm"][0] == 5.0 and rows["small"]["prostate_offset_mm"][1] == -4.0
    for v, s in variants.items():
        assert anatomy.tip_problem(s.phantom, s.guide) is None, v
        assert s.effects == load_scene(SCENES / "default.toml").effects, v  # only the anatomy differs


@pytest.mark.parametrize("variant", VARIANTS)
def test_label_map_holds_the_variants_anatomy(variants, variant):
    """1 mm voxels: prostate volume within 2 % of 4/3 pi abc and its length within a voxel; along the guide
    axis the tip's voxel boundary separates lumen from wall, and the wall runs on to the prostate as described."""
    scene = variants[variant]
    ph, tip, axis = scene.phantom, np.asarray(scene.guide.tip_mm), np.asarray(scene.guide.axis)
    image = voxelise(ph, 1.0)
    prostate = image.labels == LABELS["prostate"]
    a = np.asarray(ph.prostate_semi_axes_mm)
    assert prostate.sum() == pytest.approx(4 / 3 * np.pi * a.prod(), rel=0.02)
    xs = image.to_physical(np.argwhere(prostate))[:, 0]
    assert xs.max() - xs.min() + 1.0 == pytest.approx(2 * a[0], abs=1.0)
    steps = np.arange(-2.5, 15.0)  # voxel centres on the axis through the tip, lumen side first
    line = image.labels[tuple(np.rint(image.to_index(tip + steps[:, None] * axis)).astype(int).T)]
    assert (line[steps < 0] == LUMEN).all() and line[steps > 0][0] == LABELS["rectal_wall"]
    wall = np.argmax(line[steps > 0] != LABELS["rectal_wall"])  # wall voxels before the next tissue
    assert line[steps > 0][wall] == LABELS["prostate"]
    assert wall == pytest.approx(anatomy.clearances_mm(ph)["prostate-lumen"], abs=1.0)


@pytest.mark.parametrize(("phantom", "message"), [
    ({"prostate_center_mm": [0.0, -6.0, 35.0]},
     r"the prostate reaches 2\.00 mm into the lumen; at least 1\.0 mm .*prostate_center_mm"),
    ({"prostate_center_mm": [0.0, -3.5, 35.0]}, r"the prostate leaves 0\.50 mm of rectal wall at the lumen"),
    ({"prostate_semi_axes_mm": [20.0, 10.0, 14.0]}, r"the prostate and the bladder overlap by .*bladder_radius_mm"),
    ({"pubic_center_mm": [0.0, 14.0, 40.0]}, r"the prostate and the pubic_bone overlap by .*pubic_center_mm"),
    ({"bladder_radius_mm": 2.0, "bladder_center_mm": [0.0, 0.0, 35.0]}, r"the bladder lies inside the prostate"),
    ({"bladder_center_mm": [0.0, 4.0, 72.0]}, r"the bladder leaves the block by 5\.00 mm"),
    ({"rectum_outer_radius_mm": 7.5}, r"the rectal wall is 0\.50 mm thick"),
])
def test_a_phantom_that_is_not_anatomy_is_refused_naming_the_fields(phantom, message):
    data = load_scene(SCENES / "default.toml").model_dump(mode="json")
    data["phantom"].update(phantom)
    with pytest.raises(SceneError, match=r"phantom: .*" + message):
        parse_scene(data)


@pytest.mark.parametrize(("guide", "message"), [
    ({"tip_mm": [0.0, -15.0, 35.0]},
     r"guide.tip_mm: \[0.0, -15.0, 35.0\] is 1.00 mm off .*nearest point on it is \[0.0, -14.0, 35.0\]"),
    ({"axis": [0.0, -1.0, 0.0]}, r"guide.axis: .* does not push .* into the rectal wall"),
])
def test_a_guide_off_the_lumen_wall_is_refused(guide, message):
    data = load_scene(SCENES / "default.toml").model_dump(mode="json")
    data["guide"].update(guide)
    with pytest.raises(SceneError, match=message):
        parse_scene(data)
