"""The needle guide: its push direction, the wall patch it carries and the displacement it prescribes.

The tip moves by d a(beta), a(beta) = axis rotated by beta about tilt_normal (Rodrigues). Boundary
nodes within R = patch_radius_mm of the tip follow it with the rounded-tip weight

    u(X) = d w(r) a(beta),   w(r) = cos^2(pi r / (2 R)),   r = |X - tip|,

so the prescribed field is smooth at the patch rim. Lengths in mm, angles in degrees.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from contracts.guide import push_direction

from contracts.tet10 import boundary_faces

from .mirror import REFLECT

if TYPE_CHECKING:
    from .mesh import TetMesh
    from .scene import Guide


def direction(guide: Guide, angle_deg: float) -> np.ndarray:
    """Unit push direction a(beta) (3,): axis rotated by beta about tilt_normal (contracts.guide)."""
    return push_direction(guide.axis, guide.tilt_normal, angle_deg)


def rounded_tip_weight(r_mm: np.ndarray, radius_mm: float) -> np.ndarray:
    """w(r) = cos^2(pi r / 2R): 1 at the tip, 0 with zero slope at the rim."""
    return np.cos(0.5 * np.pi * r_mm / radius_mm) ** 2


def snap_tip(mesh: TetMesh, guide: Guide) -> tuple[int, float]:
    """(node, distance mm): the node of the rectal wall's lumen surface nearest guide.tip_mm.

    The lumen surface is the rectal wall's part of the mesh's exterior (the lumen is a hole).
    """
    if "rectal_wall" not in mesh.tissue_names:
        raise ValueError("guide.snap_mm: the mesh has no rectal_wall tissue to snap the tip to")
    ext, owner = boundary_faces(mesh.tets)
    lumen = np.unique(ext[mesh.tissue[owner] == mesh.tissue_names.index("rectal_wall")])
    if lumen.size == 0:
        raise ValueError("guide.snap_mm: the rectal wall has no exterior (lumen) surface; is the lumen labelled outside?")
    r = np.linalg.norm(mesh.nodes[lumen] - np.asarray(guide.tip_mm), axis=1)
    return int(lumen[r.argmin()]), float(r.min())


def tip(mesh: TetMesh, guide: Guide) -> np.ndarray:
    """Centre of the pushed patch (3,): guide.tip_mm, or the lumen-surface node it snaps to (guide.snap_mm)."""
    if guide.snap_mm is None:
        return np.asarray(guide.tip_mm, dtype=np.float64)
    node, dist = snap_tip(mesh, guide)
    if dist > guide.snap_mm:
        raise ValueError(f"guide.tip_mm: {list(guide.tip_mm)} is {dist:.2f} mm from the rectal wall's lumen surface "
                         f"(nearest node {node} at {np.round(mesh.nodes[node], 2).tolist()}), more than "
                         f"guide.snap_mm = {guide.snap_mm}")
    return mesh.nodes[node]


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


def prescribed(guide: Guide, *, dofs: np.ndarray, weight: np.ndarray, n_dofs: int,
               displacement_mm: float, angle_deg: float) -> np.ndarray:
    """u = d w a(beta) on the patch DOFs (k, 3), zero elsewhere; (n_dofs,)."""
    g = np.zeros(n_dofs)
    g[dofs] = displacement_mm * weight[:, None] * direction(guide, angle_deg)
    return g


def is_mirrored(guide: Guide) -> bool:
    """a(-beta) = S a(beta), S = diag(-1, 1, 1), and the tip lies on the mirror plane x = 0."""
    b = 7.0
    return guide.tip_mm[0] == 0 and np.allclose(direction(guide, -b), direction(guide, b) * REFLECT, atol=1e-12)
