"""Scene files: defaults from the paper, and errors that name the bad field."""

import numpy as np
import pytest

from fem_offline.scene import SceneError, load_scene, parse_scene

from ..conftest import SCENES


def test_default_scene_is_the_papers_setup():
    scene = load_scene(SCENES / "default.toml")
    assert scene.tissues["adipose"].youngs == pytest.approx(10.63)
    assert scene.tissues["prostate"].poisson == 0.495
    assert len(scene.sweep.angles_deg) * len(scene.sweep.displacements_mm) == 840
    assert scene.sweep.displacements_mm[0] == 0.25 and scene.sweep.displacements_mm[-1] == 10.0
    assert scene.effects.geometric_nonlinearity and not scene.effects.gravity


def _minimal(**extra):
    base = {name: {"youngs_kpa": 10.0} for name in ("adipose", "rectal_wall", "prostate", "bladder")}
    base |= {"pubic_bone": {"youngs_kpa": 2500.0, "bone": True}, "spine": {"youngs_kpa": 2500.0, "bone": True}}
    return {"tissues": base, **extra}


@pytest.mark.parametrize(
    ("patch", "field"),
    [
        ({"sweep": {"displacement_step_mm": -1}}, "sweep.displacement_step_mm"),
        ({"guide": {"patch_radius_mm": 0}}, "guide.patch_radius_mm"),
        ({"effects": {"gravity": True, "wind": True}}, "effects.wind"),
        ({"colour": "red"}, "colour"),
        ({"mesh": {"max_mm": "big"}}, "mesh.max_mm"),
        ({"guide": {"axis": [0, 0, 1]}}, "guide"),
    ],
)
def test_bad_field_is_named(patch, field):
    with pytest.raises(SceneError, match=field.replace(".", r"\.")):
        parse_scene(_minimal(**patch))


def test_bad_poisson_ratio_names_tissue():
    data = _minimal()
    data["tissues"]["prostate"]["poisson"] = 0.5
    with pytest.raises(SceneError, match=r"tissues\.prostate\.poisson"):
        parse_scene(data)


def test_missing_tissue_is_named():
    data = _minimal()
    del data["tissues"]["bladder"]
    with pytest.raises(SceneError, match="bladder"):
        parse_scene(data)


def test_toml_errors_are_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(SceneError, match="not valid TOML"):
        load_scene(bad)
    with pytest.raises(SceneError, match="no such scene file"):
        load_scene(tmp_path / "missing.toml")


def test_extends_merges_the_variant_over_its_base_table_by_table(tmp_path):
    """A variant states only what differs: its scene is the base with those keys replaced, hash included."""
    (tmp_path / "variant.toml").write_text(
        f'extends = "{SCENES / "default.toml"}"\nname = "v"\n[phantom]\nprostate_semi_axes_mm = [22.5, 10.0, 10.0]\n'
        "[tissues.prostate]\nyoungs_kpa = 70.0\n")
    variant = load_scene(tmp_path / "variant.toml")
    full = load_scene(SCENES / "default.toml").model_dump(mode="json")
    full["name"] = "v"
    full["phantom"]["prostate_semi_axes_mm"] = [22.5, 10.0, 10.0]
    full["tissues"]["prostate"]["youngs_kpa"] = 70.0
    assert variant.sha256() == parse_scene(full).sha256()
    assert variant.phantom.rectum_outer_radius_mm == 12.0 and variant.tissues["spine"].bone


def test_extends_errors_name_the_file(tmp_path):
    (tmp_path / "a.toml").write_text('extends = "b.toml"\n')
    (tmp_path / "b.toml").write_text('extends = "a.toml"\n')
    with pytest.raises(SceneError, match=r"a.toml: extends itself \(a.toml -> b.toml -> a.toml\)"):
        load_scene(tmp_path / "a.toml")
    (tmp_path / "c.toml").write_text('extends = "missing.toml"\n')
    with pytest.raises(SceneError, match=r"missing.toml: no such scene file"):
        load_scene(tmp_path / "c.toml")
    (tmp_path / "d.toml").write_text("extends = 3\n")
    with pytest.raises(SceneError, match=r"d.toml: extends: expected the file name of a scene"):
        load_scene(tmp_path / "d.toml")


def test_surface_near_tip_is_refused_on_a_label_map_scene(tmp_path):
    """Only the phantom's gmsh mesher grades by it: a label-map scene that sets it gets an error naming it."""
    (tmp_path / "p.toml").write_text(
        f'extends = "{SCENES / "patient.toml"}"\nname = "p"\n[label_map]\npath = "labels.nii.gz"\n'
        "[label_map.labels]\nprostate = 1\nrectal_wall = 2\n[guide]\ntip_mm = [1.0, -14.0, 35.0]\n"
        "[mesh]\nsurface_near_tip_mm = 1.2\n")
    with pytest.raises(SceneError, match="mesh.surface_near_tip_mm: the label-map meshers do not grade by it"):
        load_scene(tmp_path / "p.toml")


def test_patient_base_scene_gives_a_label_map_scene_the_default_physics_and_a_4_degree_sweep(tmp_path):
    """What a short patient scene loads to: default materials and effects, the grid study's uniform mesh sizes
    and pointwise element, no phantom, and the patient sweep (6 angles x 20 displacements in 0.5 mm load steps)."""
    (tmp_path / "patient.toml").write_text(
        f'extends = "{SCENES / "patient.toml"}"\nname = "p"\n[label_map]\npath = "labels.nii.gz"\n'
        "[label_map.labels]\nprostate = 1\nrectal_wall = 2\n[guide]\ntip_mm = [1.0, -14.0, 35.0]\n")
    scene, default = load_scene(tmp_path / "patient.toml"), load_scene(SCENES / "default.toml")
    uniform = load_scene(SCENES / "grid_study_base.toml")
    assert scene.phantom is None and scene.label_map.path == tmp_path / "labels.nii.gz"
    assert scene.tissues == default.tissues and scene.effects == default.effects and scene.mesh == uniform.mesh
    assert scene.effects.guide_contact and scene.effects.geometric_nonlinearity
    assert scene.guide.tip_mm == (1.0, -14.0, 35.0) and scene.guide.axis == default.guide.axis
    assert len(scene.sweep.angles_deg) == 6 and np.allclose(scene.sweep.angles_deg, np.arange(-10, 11, 4))
    assert np.allclose(scene.sweep.displacements_mm, np.arange(0.5, 10.01, 0.5))
    assert scene.solver.max_step_mm == 0.5 and scene.solver.volumetric == "pointwise"


def test_default_scene_takes_the_four_soft_tissues_stiffnesses_as_inputs():
    """Each range holds the tissue's E (the nominal); a variant drops them with `materials = false`, and a scene
    without them keeps the hash it had before the section existed (tiny.toml's, pinned here)."""
    default, tiny = load_scene(SCENES / "default.toml"), load_scene(SCENES / "tiny.toml")
    assert list(default.materials) == ["prostate", "rectal_wall", "adipose", "bladder"]
    for name, m in default.materials.items():
        assert m.youngs_kpa_range[0] < default.tissues[name].youngs < m.youngs_kpa_range[1], name
        assert m.source and 0 < m.std_percent <= 100
    assert tiny.materials is None
    assert tiny.sha256().startswith("ecc76da4a399")


@pytest.mark.parametrize("materials, field", [
    ({"prostate": {"youngs_kpa_range": [70.0, 90.0], "std_percent": 20.0}}, "materials.prostate.youngs_kpa_range"),
    ({"spine": {"youngs_kpa_range": [1000.0, 3000.0], "std_percent": 20.0}}, "materials.spine"),
    ({"liver": {"youngs_kpa_range": [1.0, 3.0], "std_percent": 20.0}}, "materials.liver"),
])
def test_a_material_input_outside_its_tissue_is_refused_by_name(materials, field):
    """The nominal E outside the range, a bone (held fixed), a tissue the scene does not have."""
    with pytest.raises(SceneError, match=field.replace(".", r"\.")):
        load_scene(SCENES / "tiny.toml", materials=materials)


def test_a_patients_measured_stiffness_gets_a_box_of_two_sigma_around_it(tmp_path):
    """measured_youngs_kpa = 35 with std_percent = 15 (sigma of ln E 0.15): the range is 35 x exp(-/+ 0.3), in place of
    the one patient.toml inherits from default.toml; the other tissues keep theirs. The tissue's own E must move with
    it (the nominal lies inside the range), else the scene is refused naming the range."""
    import math

    base = (f'extends = "{SCENES / "patient.toml"}"\nname = "p"\n[label_map]\npath = "labels.nii.gz"\n'
            "[label_map.labels]\nprostate = 1\nrectal_wall = 2\n[guide]\ntip_mm = [1.0, -14.0, 35.0]\n"
            "[materials.prostate]\nmeasured_youngs_kpa = 35.0\nstd_percent = 15.0\n")
    (tmp_path / "patient.toml").write_text(base + "[tissues.prostate]\nyoungs_kpa = 35.0\n")
    scene, default = load_scene(tmp_path / "patient.toml"), load_scene(SCENES / "default.toml")
    lo, hi = scene.materials["prostate"].youngs_kpa_range
    assert (lo, hi) == pytest.approx((35.0 * math.exp(-0.3), 35.0 * math.exp(0.3)))
    assert math.log(hi / 35.0) == pytest.approx(2 * 0.15) and "measured 35 kPa" in scene.materials["prostate"].source
    assert scene.materials["adipose"] == default.materials["adipose"]
    assert parse_scene(scene.model_dump(mode="json")).materials == scene.materials  # the dumped scene states the range
    (tmp_path / "stale.toml").write_text(base)  # the prostate's E left at the default's 65.89 kPa
    with pytest.raises(SceneError, match=r"materials\.prostate\.youngs_kpa_range"):
        load_scene(tmp_path / "stale.toml")
