"""What a tet mesh of a label map is judged by: validity, element quality, tissue volumes, conformity, surface fit.

Quality is the radius ratio q = 3 r_in / r_circ (1 for the regular tet, 0 for a flat one) and the
dihedral angles. A mesh is conforming when every face is shared by at most two tets and no node is
hanging: in one simplicial complex whose tissues share their interface nodes, that holds exactly
when no face has three or more owners and every tet face appears once or twice.
"""

from __future__ import annotations

import numpy as np

from contracts.tet10 import FACES


def signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volume (m,) mm^3 of corner tets (m, >=4)."""
    e = points[tets[:, 1:4]] - points[tets[:, [0]]]
    return np.einsum("ij,ij->i", np.cross(e[:, 0], e[:, 1]), e[:, 2]) / 6.0


def radius_ratio(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """q = 3 r_in / r_circ (m,), in [0, 1]; r_in = 3 V / area, r_circ from the circumsphere."""
    p = points[tets[:, :4]]
    vol = np.abs(signed_volumes(points, tets))
    area = sum(0.5 * np.linalg.norm(np.cross(p[:, b] - p[:, a], p[:, c] - p[:, a]), axis=1) for a, b, c in FACES)
    r_in = 3.0 * vol / area
    a, b, c = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    num = (np.einsum("ij,ij->i", a, a)[:, None] * np.cross(b, c) + np.einsum("ij,ij->i", b, b)[:, None] * np.cross(c, a)
           + np.einsum("ij,ij->i", c, c)[:, None] * np.cross(a, b))
    r_circ = np.linalg.norm(num, axis=1) / (12.0 * np.maximum(vol, 1e-300))
    return 3.0 * r_in / r_circ


def min_dihedral_deg(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Smallest dihedral angle of each tet (m,), degrees."""
    p = points[tets[:, :4]]
    normals = []
    for face, opp in zip(FACES, (3, 2, 1, 0)):
        n = np.cross(p[:, face[1]] - p[:, face[0]], p[:, face[2]] - p[:, face[0]])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        inward = np.einsum("ij,ij->i", n, p[:, opp] - p[:, face[0]]) > 0
        normals.append(np.where(inward[:, None], -n, n))  # outward
    angles = [np.degrees(np.pi - np.arccos(np.clip(np.einsum("ij,ij->i", normals[i], normals[j]), -1, 1)))
              for i in range(4) for j in range(i + 1, 4)]
    return np.min(angles, axis=0)


def tissue_volumes(points: np.ndarray, tets: np.ndarray, tissue: np.ndarray, names) -> dict[str, float]:
    vol = np.abs(signed_volumes(points, tets))
    return {name: float(vol[tissue == t].sum()) for t, name in enumerate(names)}


def face_owner_counts(tets: np.ndarray) -> np.ndarray:
    """How many tets own each distinct corner face (k,)."""
    faces = np.sort(tets[:, FACES].reshape(-1, 3), axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    return counts


def is_conforming(tets: np.ndarray) -> bool:
    """No face owned by three or more tets (a face-to-face simplicial complex over shared nodes)."""
    return bool(face_owner_counts(tets[:, :4]).max() <= 2)
