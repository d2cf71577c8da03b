"""Point location on the committed default model's mesh."""

import numpy as np

from contracts.interpolate import PointLocator
from service.model import read_model_folder

from .conftest import DEFAULT


def test_locator_finds_the_containing_tet_and_rejects_outside_points():
    folder = read_model_folder(DEFAULT)
    loc = PointLocator(folder.nodes, folder.tets)
    rng = np.random.default_rng(1)
    tets = rng.choice(len(folder.tets), 200, replace=False)
    bary = rng.dirichlet(np.ones(4), size=200)
    points = np.einsum("kv,kvd->kd", bary, folder.nodes[folder.tets[tets, :4]])
    found, b = loc.locate(points)
    assert (found >= 0).all()
    np.testing.assert_allclose(np.einsum("kv,kvd->kd", b, folder.nodes[folder.tets[found, :4]]), points, atol=1e-9)
    outside, _ = loc.locate(np.array([[0, 0, -1.0], [60, 0, 40], [0, 0, 80.5]]))
    assert (outside == -1).all()
