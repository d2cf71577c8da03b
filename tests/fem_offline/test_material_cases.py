"""The material points a first-order material model is checked at: both ends of every declared range, then the two
corners where the tissues alternate between their ends."""

import re

import numpy as np
import pytest

from fem_offline.material_cases import material_points, scaled_scene
from fem_offline.scene import load_scene

from .conftest import SCENES


def test_material_points_are_the_ends_of_each_range_then_the_alternating_corners():
    scene = load_scene(SCENES / "default.toml")
    tissues, theta = material_points(scene)
    assert tissues == ("prostate", "rectal_wall", "adipose", "bladder") and theta.shape == (10, 4)
    for i, name in enumerate(tissues):
        lo, hi = scene.materials[name].youngs_kpa_range
        e0 = scene.tissues[name].youngs
        np.testing.assert_allclose(theta[2 * i], np.eye(4)[i] * np.log(lo / e0))
        np.testing.assert_allclose(theta[2 * i + 1], np.eye(4)[i] * np.log(hi / e0))
        assert scaled_scene(scene, tissues, theta[2 * i + 1]).tissues[name].youngs == pytest.approx(hi)
    lower, upper = theta[0:8:2].sum(axis=0), theta[1:8:2].sum(axis=0)  # each tissue's two ends
    alternate = np.arange(4) % 2 == 1
    np.testing.assert_allclose(theta[-2], np.where(alternate, upper, lower))  # not all low: that changes no ratio
    np.testing.assert_allclose(theta[-1], np.where(alternate, lower, upper))


def test_a_scene_without_materials_has_nothing_to_check():
    with pytest.raises(ValueError, match="no \\[materials\\]"):
        material_points(load_scene(SCENES / "tiny.toml"))


def test_cases_from_a_material_sweep_take_its_snapshot_and_solve_the_same_fresh_states(tiny_material_sweep, tmp_path):
    """--sweep: the nominal state and the S_i are the sweep's own snapshot at the position, byte for byte, and the
    fresh solves are the ones solving everything again gives."""
    from contracts.mesh import read_mesh
    from contracts.sweep import read_manifest, snapshot_file
    from fem_offline.material_cases import solve_material_cases

    from ..conftest import TINY_MATERIALS, tiny_material_scene

    scene = tiny_material_scene(prostate=TINY_MATERIALS["prostate"], bladder=TINY_MATERIALS["bladder"])
    mesh = read_mesh(tiny_material_sweep / "mesh.npz")
    (solved,) = solve_material_cases(scene, mesh, tmp_path / "solved", [(5.0, 2.0)], workers=1)
    (taken,) = solve_material_cases(scene, mesh, tmp_path / "taken", [(5.0, 2.0)], workers=1, sweep=tiny_material_sweep)
    grid = read_manifest(tiny_material_sweep).grid
    snapshot = tiny_material_sweep / snapshot_file(grid.angles_deg.index(2.0), grid.displacements_mm.index(5.0))
    with np.load(taken) as t, np.load(solved) as s, np.load(snapshot) as z:
        for key in ("displacement", "sensitivity_prostate", "sensitivity_bladder"):
            np.testing.assert_array_equal(t[key], z[key])
            np.testing.assert_allclose(t[key], s[key], atol=1e-9 * np.abs(s[key]).max())
        np.testing.assert_allclose(t["fresh"], s["fresh"], atol=1e-9 * np.abs(s["fresh"]).max())
        np.testing.assert_array_equal(t["theta"], s["theta"])


@pytest.mark.parametrize("case, sweep, message", [
    ("5.5/0", "material", "--case 5.5/0: not a snapshot"),
    ("5/0", "plain", "holds no sensitivities"),
    ("5/0", "missing", "--sweep: .*no manifest.json"),
])
def test_material_cases_refuse_a_sweep_that_cannot_start_them(tiny_material_sweep, tiny_sweep, tmp_path, capsys,
                                                              case, sweep, message):
    from fem_offline.__main__ import main

    folder = {"material": tiny_material_sweep, "plain": tiny_sweep, "missing": tmp_path / "nothing"}[sweep]
    scene = tmp_path / "scene.toml"
    scene.write_text(f'extends = "{SCENES / "tiny.toml"}"\n\n[materials.prostate]\nyoungs_kpa_range = [50.0, 85.0]\n'
                     'std_percent = 20.0\n')
    code = main(["material-cases", "--scene", str(scene), "--mesh", str(tiny_material_sweep / "mesh.npz"),
                 "--case", case, "--sweep", str(folder), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert re.search(message, err), err
    assert not (tmp_path / "out").exists()  # refused before any solve
