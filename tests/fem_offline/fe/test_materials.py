"""Tissue constants: Young's modulus from shear-wave speed (paper eq. 1)."""

import pytest

from fem_offline.scene import Tissue


def test_youngs_from_shear_wave_speed_eq1():
    """E = 2 (1 + nu) v_s^2 rho: prostate v_s = 5.03 m/s, rho = 1008 -> 25.38 kPa (Pa -> kPa)."""
    t = Tissue(shear_wave_speed_m_s=5.03, density_kg_m3=1008.0, poisson=0.495)
    assert t.youngs == pytest.approx(2 * 1.495 * 5.03**2 * 1008 / 1000, rel=1e-12)
