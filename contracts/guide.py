"""The guide's push direction, which the FE prescribes and the service draws and streams.

    a(beta) = axis cos(beta) + (n x axis) sin(beta)     axis and n (the tilt normal) unit, axis . n = 0

that is, the axis rotated by beta about n (Rodrigues).
"""

from __future__ import annotations

import numpy as np


def push_direction(axis, tilt_normal, angle_deg: float) -> np.ndarray:
    """Unit push direction a(beta) (3,) for a guide axis and tilt normal (any length)."""
    a = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    n = np.asarray(tilt_normal, dtype=np.float64) / np.linalg.norm(tilt_normal)
    b = np.deg2rad(angle_deg)
    return a * np.cos(b) + np.cross(n, a) * np.sin(b)
