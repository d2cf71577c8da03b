"""Where the needle guide meets the wall: the tip's seat on a meshed lumen and the patch of wall nodes it carries.

Boundary nodes within R = patch_radius_mm of the tip form the patch, each with the rounded-tip weight

    w(r) = cos^2(pi r / (2 R)),   r = |X - tip|,

with which fe/guide.py prescribes u(X) = d w(r) a(beta). The patch is a node set of the mesh
(regions.py names it "guide_patch"), so meshing owns it and the FE imports it from here. Lengths in mm.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from contracts.tet10 import boundary_faces

if TYPE_CHECKING:
    from fem_offline.geometry.mesh import TetMesh
    from fem_offline.scene import Guide


def rounded_tip_weight(r_mm: np.ndarray, radius_mm: float) -> np.ndarray:
    """w(r) = cos^2(pi r / 2R): 1 at the tip, 0 with zero slope at the rim."""
    return np.cos(0.5 * np.pi * r_mm / radius_mm) ** 2


class Seat(NamedTuple):
    """Where the tip meets a meshed lumen (guide.snap_mm): the point, the lumen node nearest it, and
    how far the point is from guide.tip_mm (mm)."""

    point: np.ndarray  # (3,)
    node: int
    offset_mm: float


def _lumen_faces(mesh: TetMesh) -> np.ndarray:
    """Corner nodes (k, 3) of the rectal wall's exterior faces: the lumen surface (the lumen is a hole)."""
    if "rectal_wall" not in mesh.tissue_names:
        raise ValueError("guide.snap_mm: the mesh has no rectal_wall tissue to snap the tip to")
    ext, owner = boundary_faces(mesh.tets)
    faces = ext[mesh.tissue[owner] == mesh.tissue_names.index("rectal_wall")][:, :3]
    if faces.size == 0:
        raise ValueError("guide.snap_mm: the rectal wall has no exterior (lumen) surface; "
                         "is the lumen labelled outside?")
    return faces


def _line_crossings(origin: np.ndarray, direction: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Parameters t (h,) at which origin + t direction crosses the triangles (k, 3, 3) (Moller-Trumbore, both ways)."""
    e1, e2 = triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    h = np.cross(direction, e2)
    a = np.einsum("ki,ki->k", e1, h)
    ok = np.abs(a) > 1e-12 * np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    f = np.divide(1.0, a, out=np.zeros_like(a), where=ok)
    s = origin - triangles[:, 0]
    u = f * np.einsum("ki,ki->k", s, h)
    q = np.cross(s, e1)
    v = f * (q @ direction)
    t = f * np.einsum("ki,ki->k", e2, q)
    eps = 1e-9
    return t[ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps)]


def seat(mesh: TetMesh, guide: Guide) -> Seat:
    """Where the tip meets the rectal wall's lumen surface on this mesh (guide.snap_to).

    "axis": where the line through guide.tip_mm along guide.axis crosses the lumen surface, the
    crossing nearest tip_mm. The tip stays on the axis the user gave: a label map's lumen is a
    smoothed staircase whose nodes lie up to a voxel to the side of any given point, so the nearest
    node puts the push off the midline of a mirror-symmetric anatomy, and its left and right markers
    then move apart where the phantom's move alike (`python -m studies labelmap-truth`; CHANGELOG, issue 50).
    "node": the lumen node nearest tip_mm (label-map scenes before snap_to existed).
    """
    faces = _lumen_faces(mesh)
    tip_mm = np.asarray(guide.tip_mm, dtype=np.float64)
    lumen = np.unique(faces)
    if guide.snap_to == "node":
        r = np.linalg.norm(mesh.nodes[lumen] - tip_mm, axis=1)
        return Seat(mesh.nodes[lumen[r.argmin()]], int(lumen[r.argmin()]), float(r.min()))
    axis = np.asarray(guide.axis, dtype=np.float64) / np.linalg.norm(guide.axis)
    t = _line_crossings(tip_mm, axis, mesh.nodes[faces])
    if t.size == 0:
        raise ValueError(f"guide.tip_mm: the guide axis {list(guide.axis)} through {list(guide.tip_mm)} never crosses "
                         "the rectal wall's lumen surface")
    point = tip_mm + t[np.abs(t).argmin()] * axis
    r = np.linalg.norm(mesh.nodes[lumen] - point, axis=1)
    return Seat(point, int(lumen[r.argmin()]), float(np.abs(t).min()))


def tip(mesh: TetMesh, guide: Guide) -> np.ndarray:
    """Centre of the pushed patch (3,): guide.tip_mm, or where it seats on the lumen surface (guide.snap_mm)."""
    if guide.snap_mm is None:
        return np.asarray(guide.tip_mm, dtype=np.float64)
    where = seat(mesh, guide)
    if where.offset_mm > guide.snap_mm:
        along = " along the guide axis" if guide.snap_to == "axis" else ""
        raise ValueError(f"guide.tip_mm: {list(guide.tip_mm)} is {where.offset_mm:.2f} mm{along} from the rectal "
                         f"wall's lumen surface (at {np.round(where.point, 2).tolist()}), more than guide.snap_mm = "
                         f"{guide.snap_mm}")
    return where.point


def patch(mesh: TetMesh, guide: Guide) -> tuple[np.ndarray, np.ndarray]:
    """Boundary nodes within patch_radius_mm of the tip (k,) and their rounded-tip weights (k,)."""
    ext, _ = boundary_faces(mesh.tets)
    wall = np.unique(ext)
    r = np.linalg.norm(mesh.nodes[wall] - tip(mesh, guide), axis=1)
    radius = guide.patch_radius_mm
    inside = r < radius
    if not inside.any():
        raise ValueError(f"guide.tip_mm: no boundary node within patch_radius_mm={radius} of the tip")
    return wall[inside], rounded_tip_weight(r[inside], radius)
