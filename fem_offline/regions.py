"""Named node sets: fixed bone, table, guide patch, prostate surface and the eight markers."""

from __future__ import annotations

import numpy as np

from .mesh import TetMesh
from .scene import Scene

# Local vertex triples of the four tet faces and the VTK tetra10 edge node on each face edge.
_FACES = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
_FACE_EDGE_NODES = np.array([[4, 5, 6], [4, 8, 7], [6, 9, 7], [5, 9, 8]])


def faces(mesh: TetMesh) -> tuple[np.ndarray, np.ndarray]:
    """All tet faces as (6-node face, owning tet); interior faces appear twice."""
    six = np.concatenate([mesh.tets[:, _FACES], mesh.tets[:, _FACE_EDGE_NODES]], axis=2)  # (m, 4, 6)
    owner = np.repeat(np.arange(len(mesh.tets)), 4)
    return six.reshape(-1, 6), owner


def _face_groups(mesh: TetMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    six, owner = faces(mesh)
    key = np.sort(six[:, :3], axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return six, owner, counts[inverse.ravel()]


def boundary_faces(mesh: TetMesh) -> tuple[np.ndarray, np.ndarray]:
    """Exterior faces (6 nodes each) and the tet that owns each."""
    six, owner, count = _face_groups(mesh)
    return six[count == 1], owner[count == 1]


def interface_nodes(mesh: TetMesh, tissue: int) -> np.ndarray:
    """Nodes on the surface of one tissue: its exterior faces and its faces shared with another tissue."""
    six, owner, count = _face_groups(mesh)
    inside = mesh.tissue[owner] == tissue
    key = np.sort(six[:, :3], axis=1)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    n_inside = np.bincount(inverse.ravel(), weights=inside)[inverse.ravel()]
    surface = inside & (n_inside == 1)
    return np.unique(six[surface])


def marker_nodes(mesh: TetMesh, surface: np.ndarray, n: int = 8) -> np.ndarray:
    """Eight prostate-surface nodes nearest the octant directions of the prostate's bounding box."""
    p = mesh.nodes[surface]
    centre = 0.5 * (p.min(axis=0) + p.max(axis=0))
    half = 0.5 * (p.max(axis=0) - p.min(axis=0))
    signs = np.array([[sx, sy, sz] for sz in (1, -1) for sy in (1, -1) for sx in (-1, 1)])[:n]
    targets = centre + half * signs / np.sqrt(3.0)
    picks = [surface[np.argmin(np.linalg.norm(p - t, axis=1))] for t in targets]
    return np.asarray(picks)


def guide_weights(mesh: TetMesh, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Wall nodes within the patch radius of the tip and their rounded-tip weights cos^2(pi r / 2R)."""
    ext, _ = boundary_faces(mesh)
    wall = np.unique(ext)
    r = np.linalg.norm(mesh.nodes[wall] - np.asarray(scene.guide.tip_mm), axis=1)
    radius = scene.guide.patch_radius_mm
    inside = r < radius
    if not inside.any():
        raise ValueError(f"guide.tip_mm: no boundary node within patch_radius_mm={radius} of the tip")
    return wall[inside], np.cos(0.5 * np.pi * r[inside] / radius) ** 2


def build_node_sets(mesh: TetMesh, scene: Scene) -> TetMesh:
    """Attach the named node sets the solver and the surrogate need."""
    names = mesh.tissue_names
    bone_ids = [i for i, n in enumerate(names) if scene.tissues[n].bone]
    bones = np.unique(mesh.tets[np.isin(mesh.tissue, bone_ids)])
    ext, _ = boundary_faces(mesh)
    ext_nodes = np.unique(ext)
    z = mesh.nodes[:, 2]
    tol = 1e-6 * (z.max() - z.min())
    table = ext_nodes[z[ext_nodes] <= z.min() + tol]
    patch, _ = guide_weights(mesh, scene)
    sets = {"bones": bones, "table": table, "guide_patch": patch}
    if "prostate" in names:
        surface = interface_nodes(mesh, names.index("prostate"))
        sets["prostate_surface"] = surface
        sets["markers"] = marker_nodes(mesh, surface)
    return mesh.with_sets(**sets)
