"""The mesh a scene describes: a user's linear-tet mesh becomes the same P2 mesh as the phantom's."""

import meshio
import numpy as np

from fem_offline.geometry.meshing import mesh_for_scene
from fem_offline.scene import UserMesh


def test_user_mesh_is_read_with_tissue_tags(tiny_mesh, tiny_scene, tmp_path):
    """A plain linear-tet .msh with physical tags becomes the same P2 mesh."""
    path = tmp_path / "user.msh"
    cells = [("tetra", tiny_mesh.tets[:, :4])]
    tags = tiny_mesh.tissue + 1
    meshio.write(path,
                 meshio.Mesh(tiny_mesh.nodes, cells, cell_data={"gmsh:physical": [tags], "gmsh:geometrical": [tags]}),
                 file_format="gmsh22")
    scene = tiny_scene.model_copy(update={"phantom": None,
                                          "mesh_file": UserMesh(path=path,
                                                                tags={n: i + 1
                                                                      for i, n in enumerate(tiny_mesh.tissue_names)})})
    user = mesh_for_scene(scene)
    assert len(user.tets) == len(tiny_mesh.tets)
    assert len(user.nodes) == len(tiny_mesh.nodes), (len(user.nodes), len(tiny_mesh.nodes))
    np.testing.assert_allclose(np.sort(user.nodes, axis=0), np.sort(tiny_mesh.nodes, axis=0), atol=1e-9)
    assert len(user.node_sets["guide_patch"]) == len(tiny_mesh.node_sets["guide_patch"])
