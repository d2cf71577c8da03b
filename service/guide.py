"""The needle guide as the model knows it: a tip pushed by d along a(beta), and its pose as a 4x4 transform.

    a(beta) = axis cos(beta) + (n x axis) sin(beta)      n = tilt normal, axis and n unit, axis . n = 0

The pose (OpenIGTLink's TRANSFORM "NeedleGuide") is the guide's rigid motion from its rest pose, in
a frame at the rest tip with the mesh's axes (mm):

    R = rotation by beta about n,   t = d a(beta)        (the tip's own motion in the FE model)

The model answers for this one-parameter family only. `from_pose` refuses any other pose: off the
family by more than OFF_AXIS_MM of translation or OFF_AXIS_DEG of rotation, it raises OffAxisPose
and never projects the pose onto the family (a projected answer would be shown as the tissue's
state for a pose the guide is not in).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contracts.guide import push_direction
from contracts.model import ModelManifest

OFF_AXIS_MM = 0.1  # translation across a(beta) that is refused
OFF_AXIS_DEG = 0.1  # rotation about any axis but n that is refused
ROTATION_TOL = 1e-3  # |R^T R - I| and |det R - 1| above this: not a rotation matrix at all


class OffAxisPose(ValueError):
    """A pose outside the model's family (or not a rigid transform); the message says by how much."""


@dataclass(frozen=True)
class Guide:
    tip_mm: np.ndarray  # (3,) rest position of the tip
    axis: np.ndarray  # (3,) unit push direction at beta = 0
    tilt_normal: np.ndarray  # (3,) unit, the axis beta turns about
    patch_radius_mm: float

    @classmethod
    def of(cls, manifest: ModelManifest) -> Guide:
        """The guide of the scene the model was trained on (the manifest holds the whole validated scene)."""
        guide = manifest.scene.spec.guide
        unit = lambda v: np.asarray(v, dtype=np.float64) / np.linalg.norm(v)  # noqa: E731
        return cls(np.asarray(guide.tip_mm, dtype=np.float64), unit(guide.axis), unit(guide.tilt_normal),
                   float(guide.patch_radius_mm))

    def direction(self, angle_deg: float) -> np.ndarray:
        """Unit push direction a(beta) (contracts.guide)."""
        return push_direction(self.axis, self.tilt_normal, angle_deg)

    def rotation(self, angle_deg: float) -> np.ndarray:
        """(3, 3) rotation by beta about the tilt normal (Rodrigues)."""
        b, n = np.deg2rad(angle_deg), self.tilt_normal
        k = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
        return np.eye(3) + np.sin(b) * k + (1 - np.cos(b)) * k @ k

    def pose(self, displacement_mm: float, angle_deg: float) -> np.ndarray:
        """(4, 4) NeedleGuide transform for (d, beta)."""
        out = np.eye(4)
        out[:3, :3] = self.rotation(angle_deg)
        out[:3, 3] = displacement_mm * self.direction(angle_deg)
        return out

    def from_pose(self, matrix: np.ndarray) -> tuple[float, float]:
        """(d mm, beta deg) of a NeedleGuide transform; OffAxisPose if it is not in the family."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise OffAxisPose("the transform must be a finite 4x4 matrix")
        r, t = m[:3, :3], m[:3, 3]
        if np.abs(r.T @ r - np.eye(3)).max() > ROTATION_TOL or abs(np.linalg.det(r) - 1) > ROTATION_TOL:
            raise OffAxisPose("the rotation part is not a rotation (scaled, sheared or mirrored)")
        turned = r @ self.axis
        beta = float(np.rad2deg(np.arctan2(turned @ np.cross(self.tilt_normal, self.axis), turned @ self.axis)))
        rest = self.rotation(beta).T @ r  # what is left once the tilt is taken out
        # its angle from sin and cos together: arccos alone loses precision near 0 (float32 matrices)
        sin = np.linalg.norm([rest[2, 1] - rest[1, 2], rest[0, 2] - rest[2, 0], rest[1, 0] - rest[0, 1]]) / 2
        off_deg = float(np.rad2deg(np.arctan2(sin, (np.trace(rest) - 1) / 2)))
        if off_deg > OFF_AXIS_DEG:
            raise OffAxisPose(f"rotation {off_deg:.3f} deg about an axis other than the tilt normal "
                              f"(tolerance {OFF_AXIS_DEG} deg); the model knows only tilts about "
                              f"{self.tilt_normal.tolist()}")
        a = self.direction(beta)
        d = float(t @ a)
        off_mm = float(np.linalg.norm(t - d * a))
        if off_mm > OFF_AXIS_MM:
            raise OffAxisPose(f"translation {off_mm:.3f} mm off the guide axis (tolerance {OFF_AXIS_MM} mm); "
                              "the model knows only pushes along the tilted axis")
        return d, beta
