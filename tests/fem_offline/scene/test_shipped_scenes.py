"""Every shipped scene: its element and guide model, and a first line that says why it differs from default.toml."""

from pathlib import Path

import pytest

from fem_offline.scene import load_scene

from ..conftest import SCENES

SHIPPED = sorted(p for p in SCENES.rglob("*.toml"))
# (solver.volumetric, effects.guide_contact) of each shipped scene
EXPECTED = {
    "default.toml": ("taylor_hood", True),
    "paper_scale.toml": ("taylor_hood", True),
    "grid_study_base.toml": ("pointwise", True),
    "patient.toml": ("pointwise", True),
    "patient_box.toml": ("mean_dilatation", True),
    "tiny.toml": ("pointwise", False),
    "anatomy/small.toml": ("pointwise", True),
    "anatomy/medium.toml": ("pointwise", True),
    "anatomy/large.toml": ("pointwise", True),
}


def _name(path: Path) -> str:
    return str(path.relative_to(SCENES))


def test_every_shipped_scene_is_listed():
    assert sorted(map(_name, SHIPPED)) == sorted(EXPECTED)


@pytest.mark.parametrize("path", SHIPPED, ids=_name)
def test_element_and_guide_model(path):
    scene = load_scene(path)
    assert (scene.solver.volumetric, scene.effects.guide_contact) == EXPECTED[_name(path)]


@pytest.mark.parametrize("path", [p for p in SHIPPED if p.name != "default.toml"], ids=_name)
def test_a_scene_inherits_the_default_and_its_first_line_says_why_it_differs(path):
    """Each `extends` default.toml; where its element or guide model differs, the first line names it."""
    text = path.read_text()
    assert 'extends = "default.toml"' in text or 'extends = "../default.toml"' in text
    first = text.splitlines()[0]
    scene, default = load_scene(path), load_scene(SCENES / "default.toml")
    if scene.solver.volumetric != default.solver.volumetric:
        assert first.startswith("# Differs from default.toml") and scene.solver.volumetric in first, first
    if scene.effects.guide_contact != default.effects.guide_contact:
        assert first.startswith("# Differs from default.toml") and "glued" in first, first
    if scene.mesh != default.mesh and "paper" not in first:
        assert first.startswith("# Differs from default.toml") and ("sizes" in first or "mesh" in first), first


def test_the_schema_defaults_are_the_physics_the_studies_proved():
    """The tip in contact (the glued patch does not converge) and Taylor-Hood (the pointwise P2 element locks)."""
    from fem_offline.scene import Effects, Solver

    assert Effects().guide_contact and Solver().volumetric == "taylor_hood"
