"""Phantom: every tissue meshed with positive tets, anatomical volumes, mirror symmetry."""

import numpy as np
import pytest

from fem_offline.phantom import PRIORITY


def _volumes(nodes, tets):
    e = nodes[tets[:, 1:4]] - nodes[tets[:, [0]]]
    return np.einsum("ij,ij->i", np.cross(e[:, 0], e[:, 1]), e[:, 2]) / 6


def test_every_tissue_is_meshed_and_tets_are_positive(tiny_mesh):
    assert set(tiny_mesh.tissue_names) == set(PRIORITY)
    assert set(np.unique(tiny_mesh.tissue)) == set(range(len(PRIORITY)))
    assert (_volumes(tiny_mesh.nodes, tiny_mesh.tets) > 0).all()


def test_tissue_volumes_are_anatomical(tiny_mesh):
    """Prostate ellipsoid 40 x 20 x 20 mm: V = 4/3 pi 20 10 10 = 8378 mm^3 (within mesh error)."""
    vol = _volumes(tiny_mesh.nodes, tiny_mesh.tets)
    prostate = vol[tiny_mesh.tissue == tiny_mesh.tissue_names.index("prostate")].sum()
    assert prostate == pytest.approx(4 / 3 * np.pi * 20 * 10 * 10, rel=0.1)


def test_phantom_mesh_is_mirror_symmetric(tiny_mesh):
    """Every node has a mirror image (x -> -x) in the mesh."""
    from scipy.spatial import cKDTree

    mirrored = tiny_mesh.nodes * [-1, 1, 1]
    dist, _ = cKDTree(tiny_mesh.nodes).query(mirrored)
    assert dist.max() < 1e-9
