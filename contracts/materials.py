"""Tissue stiffnesses as model inputs: the parameter, its conversions and the manifest's description.

A material model answers for each listed tissue's Young's modulus E_i inside a declared range. Its input is

    theta_i = ln(E_i / E_i,nominal)          (0 at the scene's stiffness)

and its answer is first order in theta: u = u0 + sum_i S_i theta_i, S_i = du/d ln E_i (fem_offline.fe.sensitivity),
with a per-component std sqrt(sum_i (S_i sigma_i)^2) for independent ln E_i of std sigma_i. A shear-wave speed v_s
gives E by the paper's eq. 1, E = 2 (1 + nu) rho v_s^2, so sigma_ln E = 2 std(v_s) / v_s to first order, and
sigma_ln E = std(E) / E (sigma_ln_e: the one conversion of a stated uncertainty). The sweep stores S_i as the
snapshot array `sensitivity_<tissue>`; the model's manifest lists the inputs (MaterialsInfo) in the order of the
graph's `materials` input.

Only stiffness ratios move anything when every tissue that carries load is an input, no load is a force (gravity
off: the guide prescribes displacements) and the bones are held fixed: E_i x k for every i is the same answer
(up to the guide contact's penalty, an absolute stiffness that lets the tip sink at most its tolerance). Such a
model is judged by ratios (MaterialsInfo.by_ratios): its ranges are a box in theta up to a common shift c,

    theta is answerable  <=>  some c has lo_i <= theta_i - c <= hi_i for every i
                         <=>  max_i (theta_i - hi_i) <= min_i (theta_i - lo_i)

and the graph is fed theta - c* (ratio_point), c* the mean of theta clipped to that interval: of every point of
the box with the request's ratios, the one nearest the nominal stiffnesses. A tissue that is not an input keeps
its nominal E, so with one in the scene E x k is another patient, and the ranges hold as stated (no shift).
"""

from __future__ import annotations

import math
from typing import Sequence

from pydantic import BaseModel, ConfigDict

PARAMETER = "ln(E/E_nominal)"
# An uncertainty is drawn and sent as this many std: the error budget's total, the viewer's halo radius and the
# radius of OpenIGTLink's point (its diameter is twice that) are each HALO_SIGMAS x the std (docs/materials.md)
HALO_SIGMAS = 2.0
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


def sigma_ln_e(*, std: float, value: float, shear_wave: bool = False) -> float:
    """The std of ln E from a 1-sigma `std` of a measured `value` (E, or v_s with `shear_wave`), to first order.

    sigma_ln E = std(E) / E, and 2 std(v_s) / v_s since E ~ v_s^2 (eq. 1). A percentage p is std = p of value 100:
    sigma = p / 100 (2 p / 100 for v_s). The same first order as the propagation of sigma through S_i; the
    multiplicative reading ln(1 + p / 100) differs by about sigma^2 / 2 (0.019 at 21 %) and would make a std
    given in kPa (std / E) and the same std as a percentage disagree.
    """
    return (2.0 if shear_wave else 1.0) * std / value


class OutsideBox(ValueError):
    """theta has ratios no point of the box has: `stiff` is over its upper bound wherever `soft` is at its lower."""

    def __init__(self, message: str, *, stiff: str, soft: str):
        super().__init__(message)
        self.stiff, self.soft = stiff, soft


def ratio_shift_interval(theta: Sequence[float], lo: Sequence[float], hi: Sequence[float]) -> tuple[float, float]:
    """[max_i (theta_i - hi_i), min_i (theta_i - lo_i)]: the common shifts c that put theta - c in the box
    (empty when the first exceeds the second)."""
    return max(t - high for t, high in zip(theta, hi)), min(t - low for t, low in zip(theta, lo))


def ratio_point(theta: Sequence[float], lo: Sequence[float], hi: Sequence[float],
                tissues: Sequence[str]) -> list[float]:
    """theta - c*: the box's point with theta's ratios nearest the nominal (c* = mean theta clipped to the shifts
    that stay in the box); OutsideBox naming the tissue pair whose ratio the box cannot hold.

    c*(theta + k) = c*(theta) + k, so every E x k gives the same point. Empty interval: tissue i = argmax
    (theta_i - hi_i) is too stiff against j = argmin (theta_j - lo_j), their ratio over exp(hi_i - lo_j).
    """
    a, b = ratio_shift_interval(theta, lo, hi)
    if a > b:
        i = max(range(len(theta)), key=lambda k: theta[k] - hi[k])
        j = min(range(len(theta)), key=lambda k: theta[k] - lo[k])
        ratio, most = math.exp(theta[i] - theta[j]), math.exp(hi[i] - lo[j])
        raise OutsideBox(f"{tissues[i]}'s stiffness against {tissues[j]}'s is {ratio:.4g} x their nominal ratio, over "
                         f"the box's {most:.4g} x ({tissues[i]} up to x{math.exp(hi[i]):.4g} and {tissues[j]} down to "
                         f"x{math.exp(lo[j]):.4g} of nominal, at a common scale)",
                         stiff=tissues[i], soft=tissues[j])
    c = min(max(sum(theta) / len(theta), a), b)
    return [t - c for t in theta]


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
    # judged by ratios (the module's docstring): every load-bearing tissue an input and no force load. None in the
    # manifests written before it: contracts.model fills it in from the manifest's scene when it reads one
    by_ratios: bool | None = None

    @property
    def log_box(self) -> tuple[list[float], list[float]]:
        """Each input's range as theta = ln(E / E_nominal): (lower ends, upper ends) in the graph's order."""
        return ([math.log(m.youngs_kpa_range[0] / m.nominal_youngs_kpa) for m in self.inputs],
                [math.log(m.youngs_kpa_range[1] / m.nominal_youngs_kpa) for m in self.inputs])

    @property
    def tissues(self) -> list[str]:
        return [m.tissue for m in self.inputs]
