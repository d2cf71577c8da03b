"""beta -> -beta by reflection: on a mirror-symmetric phantom only beta >= 0 needs solving.

The mesh of a symmetric scene is built as a half plus its reflection (phantom.py), so the
reflection S = diag(-1, 1, 1) maps nodes onto nodes, tissues onto tissues, and the guide's
push direction a(-beta) onto S a(beta) (guide.is_mirrored). The discrete problem is then equivariant:
u(-beta)[i] = S u(beta)[m(i)], with m the node mirror map, to rounding: on the tiny phantom the
two solves differ by 3e-14 (linear) and 2e-15 (nonlinear) of max |u|; tests/fem_offline/test_mirror.py
asserts 1e-12 for both models.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from fem_offline.geometry.mesh import TetMesh

REFLECT = np.array([-1.0, 1.0, 1.0])


def mirror_map(mesh: TetMesh, tol_mm: float = 1e-9) -> np.ndarray | None:
    """Index of each node's mirror image, or None if the mesh is not mirror-symmetric."""
    dist, image = cKDTree(mesh.nodes).query(mesh.nodes * REFLECT)
    if dist.max() > tol_mm:
        return None
    tet_image = np.sort(image[mesh.tets[:, :4]], axis=1)
    order = {tuple(t): k for k, t in enumerate(np.sort(mesh.tets[:, :4], axis=1))}
    match = np.array([order.get(tuple(t), -1) for t in tet_image])
    if (match < 0).any() or (mesh.tissue[match] != mesh.tissue).any():
        return None
    return image


def reflect(displacement: np.ndarray, image: np.ndarray) -> np.ndarray:
    """u(-beta) from u(beta), both (n_nodes, 3)."""
    return displacement[image] * REFLECT
