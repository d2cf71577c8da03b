"""The material points a first-order material model is checked at: both ends of every declared range, then all."""

import numpy as np
import pytest

from fem_offline.material_cases import material_points, scaled_scene
from fem_offline.scene import load_scene

from .conftest import SCENES


def test_material_points_are_the_ends_of_each_range_then_all_at_once():
    scene = load_scene(SCENES / "default.toml")
    tissues, theta = material_points(scene)
    assert tissues == ("prostate", "rectal_wall", "adipose", "bladder") and theta.shape == (10, 4)
    for i, name in enumerate(tissues):
        lo, hi = scene.materials[name].youngs_kpa_range
        e0 = scene.tissues[name].youngs
        np.testing.assert_allclose(theta[2 * i], np.eye(4)[i] * np.log(lo / e0))
        np.testing.assert_allclose(theta[2 * i + 1], np.eye(4)[i] * np.log(hi / e0))
        assert scaled_scene(scene, tissues, theta[2 * i + 1]).tissues[name].youngs == pytest.approx(hi)
    np.testing.assert_allclose(theta[-2], theta[0::2][:4].sum(axis=0))
    np.testing.assert_allclose(theta[-1], theta[1::2][:4].sum(axis=0))


def test_a_scene_without_materials_has_nothing_to_check():
    with pytest.raises(ValueError, match="no \\[materials\\]"):
        material_points(load_scene(SCENES / "tiny.toml"))
