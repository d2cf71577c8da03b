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

from fem_offline.geometry.guide_patch import patch, seat, tip  # noqa: F401  node sets: meshing owns them
from fem_offline.geometry.mirror import REFLECT

if TYPE_CHECKING:
    from fem_offline.scene import Guide


def direction(guide: Guide, angle_deg: float) -> np.ndarray:
    """Unit push direction a(beta) (3,): axis rotated by beta about tilt_normal (contracts.guide)."""
    return push_direction(guide.axis, guide.tilt_normal, angle_deg)


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
