"""The material points a first-order material model is checked at: both ends of every declared range, then the two
corners where the tissues alternate between their ends."""

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
