"""P2 mesh: node layout in VTK tetra10 order and identical meshio round trips."""

import numpy as np
import pytest

from contracts.tet10 import EDGES
from fem_offline.geometry import mesh as meshmod


def test_edge_nodes_sit_at_edge_midpoints_in_vtk_order(tiny_mesh):
    """Straight-sided P2 (from_vertices): node 4 + k is the midpoint of VTK edge k."""
    n, t = tiny_mesh.nodes, tiny_mesh.tets
    mid = 0.5 * (n[t[:, EDGES[:, 0]]] + n[t[:, EDGES[:, 1]]])
    np.testing.assert_allclose(n[t[:, 4:]], mid, atol=1e-9)


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
