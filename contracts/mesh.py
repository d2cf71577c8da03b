"""The mesh every stage shares: P2 tets with tissue tags and named node sets, stored as one .npz.

Arrays in the file: nodes (n_nodes, 3) float64 mm; tets (n_tets, 10) in `tet10` (VTK) order;
tissue (n_tets,) index into tissue_names; tissue_names (k,) str; set/<name> node ids (markers
in marker order). A model folder's mesh.npz adds region/<name> and surface/<tissue> (model.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .files import atomic_savez

SET_PREFIX = "set/"


@dataclass(frozen=True)
class TetMesh:
    nodes: np.ndarray  # (n_nodes, 3) mm
    tets: np.ndarray  # (n_tets, 10) tetra10, VTK order
    tissue: np.ndarray  # (n_tets,) index into tissue_names
    tissue_names: tuple[str, ...]
    node_sets: dict[str, np.ndarray] = field(default_factory=dict)  # name -> node ids

    @property
    def n_vertices(self) -> int:
        """Corner nodes come first (scikit-fem's P2 DOF numbering)."""
        return int(self.tets[:, :4].max()) + 1

    def with_sets(self, **sets: np.ndarray) -> TetMesh:
        return TetMesh(self.nodes, self.tets, self.tissue, self.tissue_names, {**self.node_sets, **sets})


def mesh_arrays(mesh: TetMesh) -> dict[str, np.ndarray]:
    arrays = {"nodes": np.asarray(mesh.nodes, dtype=np.float64), "tets": mesh.tets.astype(np.int32),
              "tissue": mesh.tissue.astype(np.int8), "tissue_names": np.array(mesh.tissue_names, dtype=str)}
    arrays.update({SET_PREFIX + k: np.asarray(v, dtype=np.int64) for k, v in mesh.node_sets.items()})
    return arrays


def write_mesh(path: str | Path, mesh: TetMesh, **extra: np.ndarray) -> Path:
    """Write the mesh (and any extra arrays) atomically as one compressed .npz."""
    return atomic_savez(path, compressed=True, **mesh_arrays(mesh), **extra)


def read_mesh(path: str | Path) -> TetMesh:
    """Read a mesh written by `write_mesh`; a missing array is a ValueError naming it."""
    with np.load(path) as z:
        missing = sorted({"nodes", "tets", "tissue", "tissue_names"} - set(z.files))
        if missing:
            raise ValueError(f"{path}: not a mesh file (no {', '.join(missing)})")
        sets = {k[len(SET_PREFIX):]: z[k] for k in z.files if k.startswith(SET_PREFIX)}
        return TetMesh(z["nodes"], z["tets"].astype(np.int64), z["tissue"].astype(np.int32),
                       tuple(str(n) for n in z["tissue_names"]), sets)
