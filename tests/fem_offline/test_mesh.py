"""Phantom mesh: tissues, node sets, P2 node layout, symmetry and meshio round trips."""

import meshio
import numpy as np
import pytest

from contracts.tet10 import EDGES
from fem_offline import mesh as meshmod
from fem_offline.phantom import PRIORITY


def _volumes(nodes, tets):
    e = nodes[tets[:, 1:4]] - nodes[tets[:, [0]]]
    return np.einsum("ij,ij->i", np.cross(e[:, 0], e[:, 1]), e[:, 2]) / 6


def test_every_tissue_is_meshed_and_tets_are_positive(tiny_mesh):
    assert set(tiny_mesh.tissue_names) == set(PRIORITY)
    assert set(np.unique(tiny_mesh.tissue)) == set(range(len(PRIORITY)))
    assert (_volumes(tiny_mesh.nodes, tiny_mesh.tets) > 0).all()


def test_edge_nodes_sit_at_edge_midpoints_in_vtk_order(tiny_mesh):
    """Straight-sided P2 (from_vertices): node 4 + k is the midpoint of VTK edge k."""
    n, t = tiny_mesh.nodes, tiny_mesh.tets
    mid = 0.5 * (n[t[:, EDGES[:, 0]]] + n[t[:, EDGES[:, 1]]])
    np.testing.assert_allclose(n[t[:, 4:]], mid, atol=1e-9)


def test_tissue_volumes_are_anatomical(tiny_mesh):
    """Prostate ellipsoid 40 x 20 x 20 mm: V = 4/3 pi 20 10 10 = 8378 mm^3 (within mesh error)."""
    vol = _volumes(tiny_mesh.nodes, tiny_mesh.tets)
    prostate = vol[tiny_mesh.tissue == tiny_mesh.tissue_names.index("prostate")].sum()
    assert prostate == pytest.approx(4 / 3 * np.pi * 20 * 10 * 10, rel=0.1)


def test_node_sets(tiny_mesh, tiny_scene):
    sets = tiny_mesh.node_sets
    assert len(sets["markers"]) == 8 and set(sets["markers"]) <= set(sets["prostate_surface"])
    assert np.allclose(tiny_mesh.nodes[sets["table"], 2], 0.0)
    tip = np.asarray(tiny_scene.guide.tip_mm)
    assert (np.linalg.norm(tiny_mesh.nodes[sets["guide_patch"]] - tip, axis=1) < tiny_scene.guide.patch_radius_mm).all()
    bone_ids = [tiny_mesh.tissue_names.index(n) for n in ("pubic_bone", "spine")]
    assert set(np.unique(tiny_mesh.tets[np.isin(tiny_mesh.tissue, bone_ids)])) == set(sets["bones"])


def test_phantom_mesh_is_mirror_symmetric(tiny_mesh):
    """Every node has a mirror image (x -> -x) in the mesh."""
    from scipy.spatial import cKDTree

    mirrored = tiny_mesh.nodes * [-1, 1, 1]
    dist, _ = cKDTree(tiny_mesh.nodes).query(mirrored)
    assert dist.max() < 1e-9


@pytest.mark.parametrize("suffix", [".vtu", ".msh", ".xdmf"])
def test_meshio_round_trip_is_identical(tiny_mesh, tmp_path, suffix):
    path = meshmod.save(tiny_mesh, tmp_path / f"mesh{suffix}")
    back = meshmod.load(path)
    np.testing.assert_array_equal(back.nodes, tiny_mesh.nodes)
    np.testing.assert_array_equal(back.tets, tiny_mesh.tets)
    np.testing.assert_array_equal(back.tissue, tiny_mesh.tissue)
    assert back.tissue_names == tiny_mesh.tissue_names
    if suffix != ".msh":  # gmsh 2.2 files carry no point data
        assert back.node_sets.keys() == tiny_mesh.node_sets.keys()
        for name, ids in tiny_mesh.node_sets.items():
            np.testing.assert_array_equal(back.node_sets[name], ids)
    assert not list(tmp_path.glob("*.tmp*"))


def test_user_mesh_is_read_with_tissue_tags(tiny_mesh, tiny_scene, tmp_path):
    """A plain linear-tet .msh with physical tags becomes the same P2 mesh."""
    from fem_offline.meshing import mesh_for_scene
    from fem_offline.scene import UserMesh

    path = tmp_path / "user.msh"
    cells = [("tetra", tiny_mesh.tets[:, :4])]
    tags = tiny_mesh.tissue + 1
    meshio.write(path, meshio.Mesh(tiny_mesh.nodes, cells, cell_data={"gmsh:physical": [tags], "gmsh:geometrical": [tags]}), file_format="gmsh22")
    scene = tiny_scene.model_copy(update={"phantom": None, "mesh_file": UserMesh(path=path, tags={n: i + 1 for i, n in enumerate(tiny_mesh.tissue_names)})})
    user = mesh_for_scene(scene)
    assert len(user.tets) == len(tiny_mesh.tets)
    assert len(user.nodes) == len(tiny_mesh.nodes), (len(user.nodes), len(tiny_mesh.nodes))
    np.testing.assert_allclose(np.sort(user.nodes, axis=0), np.sort(tiny_mesh.nodes, axis=0), atol=1e-9)
    assert len(user.node_sets["guide_patch"]) == len(tiny_mesh.node_sets["guide_patch"])
