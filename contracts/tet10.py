"""The 10-node tetrahedron every stage shares: VTK/meshio node order, its edges and faces, P2 shape functions.

Node order (VTK/meshio tetra10): vertices 0-3, then the edge midpoints of (0,1), (1,2), (0,2),
(0,3), (1,3), (2,3). gmsh numbers the last two edge nodes the other way round.
"""

from __future__ import annotations

import numpy as np

# Corner pair of each edge node 4..9.
EDGES = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])
# gmsh tet10 -> VTK tet10 (nodes 8 and 9 swapped).
GMSH_TO_VTK = np.array([0, 1, 2, 3, 4, 5, 6, 7, 9, 8])
# Corner triples of the four faces, the edge node on each face edge, and the corner opposite each face.
FACES = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
FACE_EDGE_NODES = np.array([[4, 5, 6], [4, 8, 7], [6, 9, 7], [5, 9, 8]])
FACE_OPPOSITE = np.array([3, 2, 1, 0])


def p2_weights(bary: np.ndarray) -> np.ndarray:
    """Quadratic tet shape functions (k, 10) at barycentric coordinates (k, 4), VTK node order."""
    corners = bary * (2.0 * bary - 1.0)
    edges = 4.0 * bary[:, EDGES[:, 0]] * bary[:, EDGES[:, 1]]
    return np.concatenate([corners, edges], axis=1)


def faces(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All tet faces as (6-node face (4 m, 6), owning tet (4 m,)); interior faces appear twice."""
    six = np.concatenate([tets[:, FACES], tets[:, FACE_EDGE_NODES]], axis=2)  # (m, 4, 6)
    return six.reshape(-1, 6), np.repeat(np.arange(len(tets)), 4)


def face_multiplicity(six: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(id of each face's corner set, how many faces share it); a boundary face has count 1."""
    _, inverse, counts = np.unique(np.sort(six[:, :3], axis=1), axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    return inverse, counts[inverse]


def boundary_faces(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exterior faces (k, 6 nodes) and the tet that owns each."""
    six, owner = faces(tets)
    _, count = face_multiplicity(six)
    return six[count == 1], owner[count == 1]


def outward_triangles(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Corner triangles (k, 3) bounding a set of tets, wound so their normals point outwards."""
    six, owner = faces(tets)
    _, count = face_multiplicity(six)
    once = count == 1
    tri = six[once, :3].copy()
    opposite = tets[owner[once], np.tile(FACE_OPPOSITE, len(tets))[once]]
    normal = np.cross(nodes[tri[:, 1]] - nodes[tri[:, 0]], nodes[tri[:, 2]] - nodes[tri[:, 0]])
    inward = np.einsum("ij,ij->i", normal, nodes[opposite] - nodes[tri[:, 0]]) > 0
    tri[inward] = tri[inward][:, [0, 2, 1]]
    return tri
