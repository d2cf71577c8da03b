"""The P2 mesh on the FE side: built from corner tets, handed to scikit-fem, and read or written with meshio.

The mesh itself (contracts.mesh.TetMesh) and its .npz file belong to the contracts.

Node numbering is scikit-fem's P2 DOF numbering (vertices first, then edge midpoints), so the
FE solution vector indexes the mesh nodes directly. Tets are stored in VTK/meshio tetra10 order
(contracts.tet10): vertices 0-3, then the edges (0,1), (1,2), (0,2), (0,3), (1,3), (2,3).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from contracts.mesh import TetMesh, read_mesh, write_mesh
from contracts.tet10 import EDGES


SET_PREFIX = "set:"  # point-data name prefix of a node set in meshio formats


def skfem_mesh(mesh: TetMesh):
    """The linear (corner-vertex) skfem mesh whose P2 DOFs are these nodes."""
    from skfem import MeshTet

    return MeshTet(mesh.nodes[: mesh.n_vertices].T.copy(), mesh.tets[:, :4].T.copy())


def from_vertices(points: np.ndarray, tets4: np.ndarray, tissue: np.ndarray, names) -> TetMesh:
    """Build the P2 node set from corner vertices; tets are re-oriented to positive volume."""
    from skfem import Basis, ElementTetP2, MeshTet

    used = np.unique(tets4)
    remap = np.full(points.shape[0], -1)
    remap[used] = np.arange(used.size)
    t = remap[tets4].copy()
    p = points[used]
    e = p[t[:, 1:]] - p[t[:, [0]]]
    negative = np.einsum("ij,ij->i", np.cross(e[:, 0], e[:, 1]), e[:, 2]) < 0
    t[negative, 1], t[negative, 2] = t[negative, 2], t[negative, 1].copy()
    basis = Basis(MeshTet(p.T.copy(), t.T.copy()), ElementTetP2(), intorder=1)
    nodes = basis.doflocs.T.copy()
    tets10 = basis.element_dofs.T.copy()
    # Put the edge nodes in VTK order by matching midpoints (independent of skfem's edge order).
    mid = 0.5 * (nodes[tets10[:, EDGES[:, 0]]] + nodes[tets10[:, EDGES[:, 1]]])
    d = np.linalg.norm(mid[:, :, None, :] - nodes[tets10[:, None, 4:]], axis=-1)  # (m, 6, 6)
    order = d.argmin(axis=2)
    tets10[:, 4:] = np.take_along_axis(tets10[:, 4:], order, axis=1)
    return TetMesh(nodes, tets10, np.asarray(tissue, dtype=np.int32), tuple(names))


def save(mesh: TetMesh, path: str | Path) -> Path:
    """Write the mesh: .npz (the stages' own format), or with meshio (.vtu, .msh, .xdmf) with tissue names
    in a .json sidecar. Atomic but for .xdmf."""
    import meshio

    path = Path(path)
    if path.suffix == ".npz":
        return write_mesh(path, mesh)
    point_data = {}
    for name, ids in mesh.node_sets.items():
        mask = np.zeros(len(mesh.nodes), dtype=np.int32)
        mask[ids] = 1 + np.arange(ids.size) if name == "markers" else 1
        point_data[SET_PREFIX + name] = mask
    cell_data = {"tissue": [mesh.tissue]}
    if path.suffix == ".msh":
        cell_data = {"gmsh:physical": [mesh.tissue + 1], "gmsh:geometrical": [mesh.tissue + 1]}
    out = meshio.Mesh(mesh.nodes, [("tetra10", mesh.tets)], point_data=point_data, cell_data=cell_data)
    # XDMF names its .h5 sidecar after the file, so it cannot be renamed; it is written in place.
    tmp = path if path.suffix == ".xdmf" else path.with_name(f".{path.stem}.tmp{path.suffix}")
    meshio.write(tmp, out, **({"file_format": "gmsh22", "binary": True} if path.suffix == ".msh" else {}))
    os.replace(tmp, path)
    _write_json(path.with_suffix(".json"), {"tissue_names": list(mesh.tissue_names)})
    return path


def load(path: str | Path) -> TetMesh:
    """Read a mesh written by `save` (.npz or any meshio format) back into a TetMesh."""
    import meshio

    path = Path(path)
    if path.suffix == ".npz":
        return read_mesh(path)
    m = meshio.read(path)
    names = tuple(json.loads(path.with_suffix(".json").read_text())["tissue_names"])
    tets = m.get_cells_type("tetra10")
    key = "tissue" if "tissue" in m.cell_data else "gmsh:physical"
    tissue = np.concatenate([d for d, c in zip(m.cell_data[key], m.cells) if c.type == "tetra10"])
    tissue = tissue.astype(np.int32) - (key == "gmsh:physical")
    sets = {}
    for name, mask in m.point_data.items():
        if name.startswith(SET_PREFIX):
            ids = np.flatnonzero(mask)
            if name == SET_PREFIX + "markers":
                ids = ids[np.argsort(mask[ids])]
            sets[name[len(SET_PREFIX):]] = ids
    return TetMesh(np.asarray(m.points, dtype=np.float64), tets.astype(np.int64), tissue, names, sets)


def _write_json(path: Path, data: dict) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2))
    os.replace(tmp, path)
