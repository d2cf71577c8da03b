"""beta -> -beta by reflection: on a mirror-symmetric phantom only beta >= 0 needs solving.

The mesh of a symmetric scene is built as a half plus its reflection (phantom.py), so the
reflection S = diag(-1, 1, 1) maps nodes onto nodes, tissues onto tissues, and the guide's
push direction a(-beta) onto S a(beta). The discrete problem is then equivariant:
u(-beta)[i] = S u(beta)[m(i)], with m the node mirror map (tests/fem_offline/test_solver.py
checks it to 1e-9 for the nonlinear model).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .mesh import TetMesh
from .scene import Scene

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


def guide_is_mirrored(scene: Scene) -> bool:
    """a(-beta) = S a(beta) for the scene's guide, and the tip lies on the mirror plane."""
    g = scene.guide
    b = 7.0
    return g.tip_mm[0] == 0 and np.allclose(g.direction(-b), g.direction(b) * REFLECT, atol=1e-12)


def reflect(displacement: np.ndarray, image: np.ndarray) -> np.ndarray:
    """u(-beta) from u(beta), both (n_nodes, 3)."""
    return displacement[image] * REFLECT
