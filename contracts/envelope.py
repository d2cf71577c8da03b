"""The input envelope: the guide displacements and angles a sweep covers and a model answers for."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, model_validator

Range = tuple[float, float]


class Envelope(BaseModel):
    """d in [0, d_max] mm (the unloaded state d = 0 is known exactly), beta in [beta_min, beta_max] deg."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    displacement_mm: Range
    angle_deg: Range

    @model_validator(mode="after")
    def _ordered(self) -> Envelope:
        for name, (lo, hi) in (("displacement_mm", self.displacement_mm), ("angle_deg", self.angle_deg)):
            if not lo <= hi:
                raise ValueError(f"{name}: lower bound {lo} above upper bound {hi}")
        return self

    @classmethod
    def of_grid(cls, displacements_mm, angles_deg) -> Envelope:
        """The envelope a sweep grid spans, from rest (0 mm) to its largest displacement."""
        d, a = np.asarray(displacements_mm, dtype=float), np.asarray(angles_deg, dtype=float)
        return cls(displacement_mm=(0.0, float(d.max())), angle_deg=(float(a.min()), float(a.max())))

    def contains(self, displacement_mm: float, angle_deg: float) -> bool:
        (d0, d1), (a0, a1) = self.displacement_mm, self.angle_deg
        return d0 <= displacement_mm <= d1 and a0 <= angle_deg <= a1

    def sample(self, n: int, seed: int, *, min_displacement_mm: float = 0.0) -> list[tuple[float, float]]:
        """n cases drawn uniformly inside the envelope (d >= min_displacement_mm), rounded to 0.001."""
        rng = np.random.default_rng(seed)
        d = rng.uniform(max(min_displacement_mm, self.displacement_mm[0]), self.displacement_mm[1], n)
        a = rng.uniform(*self.angle_deg, n)
        return [(round(float(x), 3), round(float(y), 3)) for x, y in zip(d, a)]

