"""Point location and quadratic interpolation inside tets."""

import numpy as np

from service.model import PointLocator, read_model_folder, p2_weights

from conftest import DEFAULT


def test_p2_weights_partition_unity_and_reproduce_quadratics():
    """sum N_i = 1, and a quadratic f(x) sampled at the 10 nodes is interpolated exactly."""
    rng = np.random.default_rng(0)
    corners = rng.normal(size=(4, 3))
    edges = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])
    nodes = np.concatenate([corners, corners[edges].mean(axis=1)])
    f = lambda p: 1 + p[..., 0] - 2 * p[..., 1] * p[..., 2] + 3 * p[..., 0] ** 2  # noqa: E731
    bary = rng.dirichlet(np.ones(4), size=20)
    w = p2_weights(bary)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(w @ f(nodes), f(bary @ corners), atol=1e-12)


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
