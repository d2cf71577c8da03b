"""Named node sets: fixed bone, table, guide patch, prostate surface and the eight markers."""

from __future__ import annotations

import numpy as np

from contracts.tet10 import boundary_faces, face_multiplicity, faces

from fem_offline.geometry import guide_patch
from fem_offline.geometry.mesh import TetMesh
from fem_offline.scene import Scene


def interface_nodes(mesh: TetMesh, tissue: int) -> np.ndarray:
    """Nodes on the surface of one tissue: its exterior faces and its faces shared with another tissue."""
    six, owner = faces(mesh.tets)
    group, _ = face_multiplicity(six)
    inside = mesh.tissue[owner] == tissue
    n_inside = np.bincount(group, weights=inside)[group]
    surface = inside & (n_inside == 1)
    return np.unique(six[surface])


def bone_nodes(mesh: TetMesh, scene: Scene) -> np.ndarray:
    """Every node of a tet whose tissue is marked `bone` in the scene (sorted)."""
    bone_ids = [i for i, n in enumerate(mesh.tissue_names) if scene.tissues[n].bone]
    return np.unique(mesh.tets[np.isin(mesh.tissue, bone_ids)])


def table_nodes(mesh: TetMesh) -> np.ndarray:
    """Boundary nodes on the bottom face z = z_min (to 1e-6 of the height)."""
    ext, _ = boundary_faces(mesh.tets)
    ext_nodes = np.unique(ext)
    z = mesh.nodes[:, 2]
    tol = 1e-6 * (z.max() - z.min())
    return ext_nodes[z[ext_nodes] <= z.min() + tol]


# The octant (signs of x, y, z from the prostate's centre) of each marker, in marker order.
MARKER_OCTANTS = np.array([[sx, sy, sz] for sz in (1, -1) for sy in (1, -1) for sx in (-1, 1)])


def marker_names() -> list[str]:
    """A name per marker, its octant in marker order: 'x-y+z+' lies on the -x, +y, +z side of the prostate's centre."""
    return ["".join(f"{axis}{'+' if s > 0 else '-'}" for axis, s in zip("xyz", signs)) for signs in MARKER_OCTANTS]


def marker_nodes(mesh: TetMesh, surface: np.ndarray, n: int = 8) -> np.ndarray:
    """Eight prostate-surface nodes nearest the octant directions of the prostate's bounding box."""
    p = mesh.nodes[surface]
    centre = 0.5 * (p.min(axis=0) + p.max(axis=0))
    half = 0.5 * (p.max(axis=0) - p.min(axis=0))
    targets = centre + half * MARKER_OCTANTS[:n] / np.sqrt(3.0)
    picks = [surface[np.argmin(np.linalg.norm(p - t, axis=1))] for t in targets]
    return np.asarray(picks)


def build_node_sets(mesh: TetMesh, scene: Scene) -> TetMesh:
    """Attach the named node sets the solver and the surrogate need."""
    names = mesh.tissue_names
    patch, _ = guide_patch.patch(mesh, scene.guide)
    sets = {"bones": bone_nodes(mesh, scene), "table": table_nodes(mesh), "guide_patch": patch}
    if "prostate" in names:
        surface = interface_nodes(mesh, names.index("prostate"))
        sets["prostate_surface"] = surface
        sets["markers"] = marker_nodes(mesh, surface)
    return mesh.with_sets(**sets)
