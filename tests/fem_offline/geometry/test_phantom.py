"""Phantom: every tissue meshed with positive tets, anatomical volumes, mirror symmetry."""

import numpy as np
import pytest

from fem_offline.geometry.phantom import PRIORITY


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


def _surface_spacing_near_tip(scene, mesh, radius_mm=10.0):
    """Median distance from each prostate-surface mesh vertex within radius_mm of the tip to its nearest other one."""
    from scipy.spatial import cKDTree

    vertices = np.intersect1d(np.asarray(mesh.node_sets["prostate_surface"]), np.unique(mesh.tets[:, :4]))
    p = mesh.nodes[vertices]
    d, _ = cKDTree(p).query(p, k=2)
    return float(np.median(d[np.linalg.norm(p - np.asarray(scene.guide.tip_mm), axis=1) < radius_mm, 1]))


def test_surface_near_tip_refines_the_prostate_surface_by_the_tip(tiny_scene, tiny_mesh):
    """mesh.surface_near_tip_mm = 1.5 (guide_mm 2.5): the prostate's surface vertices near the tip are about 1.5 mm
    apart, not 2 as without it; the mesh stays valid."""
    from fem_offline.geometry.meshing import mesh_for_scene

    scene = tiny_scene.model_copy(update={"mesh": tiny_scene.mesh.model_copy(update={"surface_near_tip_mm": 1.5})})
    mesh = mesh_for_scene(scene)
    assert (_volumes(mesh.nodes, mesh.tets) > 0).all()
    without, with_zone = _surface_spacing_near_tip(tiny_scene, tiny_mesh), _surface_spacing_near_tip(scene, mesh)
    assert with_zone < 0.8 * without and with_zone < 1.15 * 1.5, (without, with_zone)
