"""Tissue stiffnesses as model inputs: the parameter, its conversions and the manifest's description.

A material model answers for each listed tissue's Young's modulus E_i inside a declared range. Its input is

    theta_i = ln(E_i / E_i,nominal)          (0 at the scene's stiffness)

and its answer is first order in theta: u = u0 + sum_i S_i theta_i, S_i = du/d ln E_i (fem_offline.fe.sensitivity),
with a per-component std sqrt(sum_i (S_i sigma_i)^2) for independent ln E_i of std sigma_i. A shear-wave speed v_s
gives E by the paper's eq. 1, E = 2 (1 + nu) rho v_s^2, so sigma_ln E = 2 std(v_s) / v_s to first order, and
sigma_ln E = std(E) / E. The sweep stores S_i as the snapshot array `sensitivity_<tissue>`; the model's manifest
lists the inputs (MaterialsInfo) in the order of the graph's `materials` input.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict

PARAMETER = "ln(E/E_nominal)"
SENSITIVITY_PREFIX = "sensitivity_"


def sensitivity_key(tissue: str) -> str:
    """The snapshot array holding S_i = du/d ln E_i (n_nodes, 3) mm of `tissue`."""
    return f"{SENSITIVITY_PREFIX}{tissue}"


def youngs_from_shear_wave_kpa(*, shear_wave_speed_m_s: float, density_kg_m3: float, poisson: float) -> float:
    """E = 2 (1 + nu) v_s^2 rho (paper eq. 1), in kPa: v_s in m/s, rho in kg/m^3 give Pa."""
    return 2.0 * (1.0 + poisson) * shear_wave_speed_m_s**2 * density_kg_m3 / 1e3


def shear_wave_from_youngs_m_s(*, youngs_kpa: float, density_kg_m3: float, poisson: float) -> float:
    """v_s = sqrt(E / (2 (1 + nu) rho)) in m/s, the inverse of eq. 1."""
    return math.sqrt(youngs_kpa * 1e3 / (2.0 * (1.0 + poisson) * density_kg_m3))


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class MaterialInput(_Frozen):
    """One tissue whose stiffness the model takes as input."""

    tissue: str
    nominal_youngs_kpa: float  # theta = 0: the stiffness the sweep was solved at
    youngs_kpa_range: tuple[float, float]  # what the model answers for; the service refuses the rest (422)
    std_percent: float  # default 1-sigma measurement uncertainty of E, % of E
    poisson: float  # for eq. 1
    density_kg_m3: float  # for eq. 1
    source: str = ""  # where the range and the uncertainty come from

    @property
    def shear_wave_range_m_s(self) -> tuple[float, float]:
        """The range as shear-wave speeds (eq. 1)."""
        lo, hi = (shear_wave_from_youngs_m_s(youngs_kpa=e, density_kg_m3=self.density_kg_m3, poisson=self.poisson)
                  for e in self.youngs_kpa_range)
        return lo, hi


class MaterialRegionAccuracy(_Frozen):
    """Largest error (mm) at one region of the first-order material model, over the checked material points."""

    first_order_mm: float  # FE u0 + sum S_i theta_i against a fresh FE solve at theta (the material part alone)
    model_mm: float  # the served model (ONNX) at theta against that fresh FE solve (surrogate + first order)


class MaterialAccuracy(_Frozen):
    """The first-order material model checked against fresh FE solves at held-out material points."""

    reference: str
    n_points: int  # the points solved and compared
    regions: dict[str, MaterialRegionAccuracy]
    unsolved: list[str] = []  # the points where the FE found no equilibrium (guide position, theta, why): not compared


class MaterialsInfo(_Frozen):
    """The manifest's `materials` section: the inputs in the graph's order, and how accurate the material part is."""

    parameter: str = PARAMETER
    inputs: list[MaterialInput]
    accuracy: MaterialAccuracy | None = None  # None: not checked against fresh FE (training material-check)

    @property
    def tissues(self) -> list[str]:
        return [m.tissue for m in self.inputs]
