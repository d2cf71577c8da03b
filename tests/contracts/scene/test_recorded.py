"""A scene as a manifest recorded it (contracts/scene/recorded.py, parse.recorded_scene): a later field it lacks reads
at its value from before, not at today's default; written back it is the same JSON; it hashes to what was recorded;
and it is not judged again as a user's scene."""

import json
from pathlib import Path

import pytest

from contracts.model import read_manifest
from contracts.scene import SceneError, parse_scene, recorded_scene
from contracts.scene.recorded import LATER_FIELDS
from fem_offline.scene import load_scene

from ...conftest import SCENES

DEFAULT_MODEL = Path(__file__).resolve().parents[3] / "models" / "default"


def _without(data: dict, section: str | None, key: str) -> dict:
    """A scene's JSON as a manifest written before the field (section, key) existed holds it."""
    data = json.loads(json.dumps(data))
    (data if section is None else data[section]).pop(key)
    return data


@pytest.fixture(scope="module")
def default():
    return load_scene(SCENES / "default.toml")


def test_a_later_field_a_manifest_lacks_reads_at_its_value_from_before_not_todays_default(default):
    """Before effects.guide_contact the guide was the glued patch, before solver.volumetric the element pointwise:
    a manifest of that time lacking them means those, where a user's scene lacking them gets today's defaults."""
    data = _without(_without(default.model_dump(mode="json"), "effects", "guide_contact"), "solver", "volumetric")
    recorded, today = recorded_scene(data), parse_scene(data)
    assert (recorded.effects.guide_contact, recorded.solver.volumetric) == (False, "pointwise")
    assert (today.effects.guide_contact, today.solver.volumetric) == (True, "taylor_hood")
    stated = default.model_copy(update={"effects": default.effects.model_copy(update={"guide_contact": False}),
                                        "solver": default.solver.model_copy(update={"volumetric": "pointwise"})})
    assert recorded == stated and recorded.sha256() == stated.sha256()


@pytest.mark.parametrize("section, key", [k for k in LATER_FIELDS if k[0] != "label_map"])
def test_a_recorded_scene_is_written_back_as_the_json_it_was_read_from(default, section, key):
    """Each later field left out of a scene's JSON (at its value from before) stays out when the scene is dumped,
    and the scene keeps its hash; changed away from that value, the field is written again."""
    full = default.model_copy(update={"materials": None}).model_dump(mode="json")  # every field at its value before
    full["guide"].update(snap_to="node", tip_radius_mm=6.0, contact_stiffness_kpa_mm=3e4, contact_tol_mm=0.005)
    full["effects"]["guide_contact"], full["solver"]["volumetric"] = False, "pointwise"
    data = _without(full, section, key)
    scene = recorded_scene(data)
    assert json.dumps(scene.model_dump(mode="json")) == json.dumps(data)
    assert scene.sha256() == parse_scene(full).sha256()
    if section == "solver":
        moved = scene.model_copy(update={"solver": scene.solver.model_copy(update={"volumetric": "taylor_hood"})})
        assert moved.model_dump(mode="json")["solver"]["volumetric"] == "taylor_hood"


def test_models_default_reads_its_scene_as_solved_and_writes_it_back_unchanged():
    """Its manifest predates guide.contact_stiffness_per_mm: the typed scene hashes to the sha256 it records, equals
    default.toml's physics, and the manifest's scene is dumped as the same bytes."""
    raw = json.loads((DEFAULT_MODEL / "manifest.json").read_text())
    assert "contact_stiffness_per_mm" not in raw["scene"]["spec"]["guide"]
    manifest = read_manifest(DEFAULT_MODEL)
    scene = manifest.scene.spec
    assert scene.sha256() == raw["scene"]["sha256"] == load_scene(SCENES / "default.toml").sha256()
    assert scene.guide.contact_stiffness_per_mm is None
    assert json.dumps(json.loads(manifest.model_dump_json())["scene"]) == json.dumps(raw["scene"])  # key order too


def test_a_recorded_scene_is_not_judged_again_but_its_structure_is(default):
    """A phantom whose prostate cuts into the bladder is refused from a user, read from a manifest (a check made
    stricter since must not make a model unreadable); an unknown field or a missing one is refused from both,
    naming the field."""
    data = default.model_dump(mode="json")
    data["phantom"]["bladder_center_mm"] = [0.0, 0.0, 45.0]
    with pytest.raises(SceneError, match="overlap"):
        parse_scene(data)
    assert recorded_scene(data).phantom.bladder_center_mm == (0.0, 0.0, 45.0)
    for bad, field in [({**data, "colour": "red"}, "colour"), (_without(data, None, "tissues"), "tissues")]:
        with pytest.raises(SceneError, match=field):
            recorded_scene(bad)
