"""Boundary conditions and the node sets they hold (u in mm):

    bones (effects.fixed_bones):  u = 0 on every node of a bone tissue
    table (effects.table):        u_z = 0 on the bottom face z = z_min (frictionless sliding)
    guide:                        u = d w(X) a(beta) on the wall patch (guide.py); none with
                                  effects.guide_contact, where the tip touches the wall (contact.py)
A guide-patch DOF is prescribed by the guide even where a bone or the table would fix it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from fem_offline.fe import guide

if TYPE_CHECKING:
    from fem_offline.geometry.mesh import TetMesh
    from fem_offline.scene import Scene


class Constraints(NamedTuple):
    fixed_dofs: np.ndarray  # (n_fixed,) held at zero
    guide_dofs: np.ndarray  # (n_patch, 3)
    guide_weight: np.ndarray  # (n_patch,) rounded-tip weight w


def constraints(scene: Scene, mesh: TetMesh) -> Constraints:
    """The DOFs the switched-on effects fix, and the guide's DOFs and weights (node sets from regions.py)."""
    fixed = []
    if scene.effects.fixed_bones:
        fixed.append((3 * mesh.node_sets["bones"][:, None] + np.arange(3)).ravel())
    if scene.effects.table:
        fixed.append(3 * mesh.node_sets["table"] + 2)
    if scene.effects.guide_contact:
        patch, weight = np.zeros(0, dtype=np.int64), np.zeros(0)
    else:
        patch, weight = guide.patch(mesh, scene.guide)
    guide_dofs = 3 * patch[:, None] + np.arange(3)
    fixed = np.setdiff1d(np.concatenate(fixed) if fixed else np.array([], int), guide_dofs.ravel())
    return Constraints(fixed, guide_dofs, weight)
