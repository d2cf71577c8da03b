"""The shared tet10 tables: faces, boundary faces and outward triangles on a two-tet mesh."""

import numpy as np
import pytest

from contracts.tet10 import EDGES, FACE_EDGE_NODES, FACES, boundary_faces, outward_triangles


def _two_tets():
    corners = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
    t4 = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])  # both positively oriented
    mids, tets = [], []
    for t in t4:
        ids = list(t)
        for a, b in EDGES:
            key = tuple(sorted((t[a], t[b])))
            if key not in mids:
                mids.append(key)
            ids.append(len(corners) + mids.index(key))
        tets.append(ids)
    nodes = np.vstack([corners, [0.5 * (corners[a] + corners[b]) for a, b in mids]])
    return nodes, np.array(tets)


def test_face_edge_nodes_lie_on_their_faces():
    nodes, tets = _two_tets()
    for face, edge_nodes in zip(FACES, FACE_EDGE_NODES):
        for t in tets:
            mids = {tuple(0.5 * (nodes[t[a]] + nodes[t[b]])) for a in face for b in face if a < b}
            assert {tuple(nodes[t[e]]) for e in edge_nodes} == mids


def test_shared_face_is_interior_and_surface_is_closed_outward():
    nodes, tets = _two_tets()
    six, owner = boundary_faces(tets)
    assert len(six) == 6 and set(owner) == {0, 1}  # 8 faces, one shared
    tri = outward_triangles(nodes, tets)
    p = nodes[tri]
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
    expected = sum(abs(np.linalg.det(nodes[t[1:4]] - nodes[t[0]])) / 6 for t in tets)
    assert volume == pytest.approx(expected, rel=1e-12)
