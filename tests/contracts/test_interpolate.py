"""Point location and P2 interpolation in tet10 meshes (contracts/interpolate.py)."""

import itertools

import numpy as np
import pytest

from contracts.interpolate import PointLocator, interpolate, interpolation_matrix
from contracts.tet10 import EDGES, p2_weights


def quadratic(p):
    """A full quadratic in x, y, z: P2 elements reproduce it exactly."""
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return 1 + x - 2 * y * z + 3 * x**2 - z**2 + 0.5 * x * y


def box_mesh(n: int, size_mm: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """Tet10 mesh of the cube [0, size]^3: n^3 cubes, 6 Kuhn tets each, edge nodes at the midpoints."""
    g = np.linspace(0.0, size_mm, n + 1)
    corners = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    tets = []
    for perm in itertools.permutations(range(3)):  # the 6 monotone paths from (0,0,0) to (1,1,1)
        steps = np.cumsum([np.eye(3, dtype=int)[a] for a in perm], axis=0)
        path = [np.zeros(3, int), *steps]
        tets.append(np.stack([idx[i:i + n, j:j + n, k:k + n].ravel() for i, j, k in path], axis=1))
    tets = np.concatenate(tets)  # (6 n^3, 4)
    pairs = np.sort(tets[:, EDGES].reshape(-1, 2), axis=1)
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    nodes = np.concatenate([corners, corners[unique].mean(axis=1)])
    return nodes, np.concatenate([tets, len(corners) + inverse.reshape(-1, 6)], axis=1)


def test_p2_weights_partition_unity_and_reproduce_quadratics():
    """sum N_i = 1, and a quadratic f(x) sampled at the 10 nodes is interpolated exactly."""
    rng = np.random.default_rng(0)
    corners = rng.normal(size=(4, 3))
    nodes = np.concatenate([corners, corners[EDGES].mean(axis=1)])
    bary = rng.dirichlet(np.ones(4), size=20)
    w = p2_weights(bary)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(w @ quadratic(nodes), quadratic(bary @ corners), atol=1e-12)


def test_locate_finds_the_containing_tet_and_rejects_outside_points():
    nodes, tets = box_mesh(3)
    rng = np.random.default_rng(1)
    which = rng.integers(len(tets), size=100)
    bary = rng.dirichlet(np.ones(4), size=100)
    points = np.einsum("kv,kvd->kd", bary, nodes[tets[which, :4]])
    tet, b = PointLocator(nodes, tets).locate(np.concatenate([points, [[-0.5, 5, 5], [5, 5, 10.5]]]))
    np.testing.assert_array_equal(tet[:100], which)
    np.testing.assert_allclose(b[:100], bary, atol=1e-12)
    np.testing.assert_array_equal(tet[100:], -1)


def test_nearest_clips_outside_points_to_the_boundary():
    """Just outside the face x = 10, nearest=True gives the value at the closest boundary point."""
    nodes, tets = box_mesh(2)
    points = np.array([[10.2, 3.0, 4.0], [10.05, 7.0, 1.0]])
    tet, bary = PointLocator(nodes, tets).locate(points, nearest=True)
    assert (tet >= 0).all()
    np.testing.assert_allclose(bary.sum(axis=1), 1.0)
    at = np.einsum("kv,kvd->kd", bary, nodes[tets[tet, :4]])
    np.testing.assert_allclose(at, [[10.0, 3.0, 4.0], [10.0, 7.0, 1.0]], atol=1e-9)


def test_interpolate_reproduces_a_quadratic_at_located_points():
    nodes, tets = box_mesh(2)
    points = np.random.default_rng(2).uniform(0, 10, size=(50, 3))
    tet, bary = PointLocator(nodes, tets).locate(points)
    np.testing.assert_allclose(interpolate(quadratic(nodes)[tets[tet]], bary), quadratic(points), atol=1e-9)


def test_interpolation_matrix_transfers_a_quadratic_between_meshes():
    """W from a coarse mesh to a finer mesh's nodes carries a quadratic over exactly; its rows sum to 1."""
    coarse, coarse_tets = box_mesh(2)
    fine, _ = box_mesh(5)
    W = interpolation_matrix(coarse, coarse_tets, fine)
    assert W.shape == (len(fine), len(coarse))
    np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(W @ quadratic(coarse), quadratic(fine), atol=1e-9)


def test_interpolation_matrix_refuses_outside_points_unless_nearest():
    nodes, tets = box_mesh(2)
    points = np.array([[5.0, 5.0, 5.0], [5.0, 5.0, 10.3]])
    with pytest.raises(ValueError, match=r"1 of 2 points are outside the mesh \(first: points\[1\]"):
        interpolation_matrix(nodes, tets, points)
    W = interpolation_matrix(nodes, tets, points, nearest=True)
    np.testing.assert_allclose(W @ quadratic(nodes), quadratic(np.array([[5, 5, 5], [5, 5, 10.0]])), atol=1e-9)


def box_with_hole(n: int) -> tuple[np.ndarray, np.ndarray]:
    """box_mesh(n) less the tets whose centroid lies in the central 4 mm cube: a hole inside the bounding box."""
    nodes, tets = box_mesh(n)
    centroid = nodes[tets[:, :4]].mean(axis=1)
    return nodes, tets[~np.all(np.abs(centroid - 5.0) < 2.0, axis=1)]


@pytest.mark.parametrize("n", [4, 8, 16])
def test_barycentric_tests_per_point_are_bounded_whatever_the_mesh_size(n):
    """Points anywhere in the box, the hole included, cost a few barycentric tests each, not n_tets.

    A point of a Kuhn mesh lies in the bounding boxes of at most 6 tets x 8 cubes around a corner.
    """
    nodes, tets = box_with_hole(n)
    points = np.random.default_rng(n).uniform(0.0, 10.0, size=(2000, 3))
    point, _ = PointLocator(nodes, tets).candidates(points)
    per_point = np.bincount(point, minlength=len(points))
    assert per_point.max() <= 48, (per_point.max(), len(tets))


def test_a_point_within_tol_of_a_boundary_face_is_inside_and_beyond_it_is_not():
    """Float32 rounding moves a boundary node off its face by ~1e-6 mm: still inside; 10 tol out is not."""
    nodes, tets = box_mesh(3)
    loc = PointLocator(nodes, tets)
    on_face = np.array([[10.0, 2.0, 3.0], [10.0, 5.0, 5.0], [4.0, 0.0, 7.0]])
    outward = np.array([[1.0, 0, 0], [1.0, 0, 0], [0, -1.0, 0]])
    inside, _ = loc.locate(on_face + 0.5 * loc.tol_mm * outward)
    outside, _ = loc.locate(on_face + 10 * loc.tol_mm * outward)
    assert (inside >= 0).all() and (outside == -1).all()
