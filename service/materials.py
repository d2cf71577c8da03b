"""A material model's stiffness inputs at the service: the request's `materials`, the graph's vectors, the error budget.

A request may give, per tissue the model lists (GET /model, `materials.inputs`),

    {"youngs_kpa": 70.0}  or  {"shear_wave_speed_m_s": 4.3}      (eq. 1: E = 2 (1 + nu) rho v_s^2, the
                                                                   manifest's nu and rho)
    and optionally "std_percent" (of that value) or "std" (in its unit)

A tissue left out is at its nominal E with the scene's stated uncertainty (`std_percent` of E), so an old client
sending only (d, beta) gets the nominal answer. The graph takes theta = ln(E / E_nominal) and sigma = the std of
ln E (contracts.materials.sigma_ln_e: std(E) / E, or 2 std(v_s) / v_s, to first order).

A model judged by ratios (MaterialsInfo.by_ratios: every load-bearing tissue an input) takes any E within
RATIO_SPAN of the nominal: the request is judged by its ratios, and the graph answers at the box's point with those
ratios nearest the nominal (contracts.materials.ratio_point), so every E x k gets the answer of E; ratios no point of
the box has are a 422 naming a tissue and the bound it crossed (`materials.prostate`, type outside_box). Otherwise each
value must lie inside its declared range (422 naming e.g. `materials.prostate.youngs_kpa`).

Every answer of a material model carries `std_mm` (per returned point, the std of x, y and z: 1 sigma) and an
`error_budget`: the surrogate's and the FE discretisation's bounds and the first-order material model's error
(`*_bound_mm`: the manifest's accuracy, the largest error measured, each with what it was measured against), the
largest std length at the returned points (`material_std_mm_max`, 1 sigma), and total_mm = the three bounds +
HALO_SIGMAS (2) x that std. Whatever draws or sends an uncertainty as a
size (the viewer's halo, OpenIGTLink's point diameter) draws the same HALO_SIGMAS x std radius.
"""

from __future__ import annotations

import math
from typing import Annotated, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator
from pydantic_core import PydanticCustomError

from contracts.materials import (HALO_SIGMAS, MaterialInput, MaterialsInfo, OutsideBox, ratio_point,
                                 shear_wave_from_youngs_m_s, sigma_ln_e, youngs_from_shear_wave_kpa)
from contracts.model import ModelManifest

from .http import RequestProblem

NO_MATERIALS = "this model takes no material inputs"
STD_SIGMAS = HALO_SIGMAS  # total_mm counts the material uncertainty at 2 std, as the viewer and OpenIGTLink draw it
# judged by ratios, a value may be this factor off its nominal either way: a common scale of 1e-6 .. 1e6 is far past
# any measurement, and ln E and the ratios stay finite (E = 5e-324 gave ln 0, and 1e307 an overflowing ratio)
RATIO_SPAN = 1e6


def _given(*names: str) -> dict:
    """The JSON schema of an object in which each of `names` is present and not null."""
    return {"required": list(names), "properties": {name: {"type": "number"} for name in names}}


class TissueValueBase(BaseModel):
    """One tissue's stiffness in a request: E or a shear-wave speed, with an optional uncertainty."""

    # the rules of _one_each, in the schema too (as region and points in schemas.py); a field is given when
    # it is present and not null, as the validator reads it
    model_config = ConfigDict(extra="forbid", json_schema_extra={"allOf": [
        {"not": _given("youngs_kpa", "shear_wave_speed_m_s")},
        {"not": _given("std_percent", "std")},
        {"if": _given("std"), "then": {"anyOf": [_given("youngs_kpa"), _given("shear_wave_speed_m_s")]}}]})

    youngs_kpa: Optional[float] = None
    shear_wave_speed_m_s: Optional[float] = None
    std_percent: Optional[float] = None
    std: Optional[float] = None

    @model_validator(mode="after")
    def _one_each(self):
        if self.youngs_kpa is not None and self.shear_wave_speed_m_s is not None:
            raise ValueError("give youngs_kpa or shear_wave_speed_m_s, not both")
        if self.std_percent is not None and self.std is not None:
            raise ValueError("give std_percent or std, not both")
        if self.std is not None and self.youngs_kpa is None and self.shear_wave_speed_m_s is None:
            raise ValueError("std is in the unit of youngs_kpa or shear_wave_speed_m_s: give one of them")
        value = self.youngs_kpa if self.youngs_kpa is not None else self.shear_wave_speed_m_s
        if self.std is not None and self.std > value:
            # so sigma stays finite (a std of 1e308 gave infinite std_mm): at most the value, as std_percent's 100;
            # a bound between two fields that JSON schema cannot state, hence its own type
            raise PydanticCustomError("std_over_value", "std {std:g} is over the value {value:g}: at most 100 % of it",
                                      {"std": self.std, "value": value})
        return self


def _number(what: str, **bounds):
    return Annotated[Optional[float], Field(None, strict=True, allow_inf_nan=False, description=what, **bounds)]


def _tissue_model(m: MaterialInput, *, by_ratios: bool) -> type[TissueValueBase]:
    """One tissue's request model: any E within RATIO_SPAN of the nominal when judged by ratios (the box is checked on
    the whole request), else inside its declared range."""
    (e_lo, e_hi), (v_lo, v_hi) = m.youngs_kpa_range, m.shear_wave_range_m_s
    v_lo, v_hi = math.floor(v_lo * 1e4) / 1e4, math.ceil(v_hi * 1e4) / 1e4  # the E range's ends stay inside
    if by_ratios:  # any common scale within RATIO_SPAN of the nominal: finite theta and ratios for every value
        e_lo, e_hi = m.nominal_youngs_kpa / RATIO_SPAN, m.nominal_youngs_kpa * RATIO_SPAN
        v_lo, v_hi = (shear_wave_from_youngs_m_s(youngs_kpa=e, density_kg_m3=m.density_kg_m3, poisson=m.poisson)
                      for e in (e_lo, e_hi))
        v_lo, v_hi = math.ceil(v_lo * 1e6) / 1e6, math.floor(v_hi * 1e4) / 1e4  # their E stays inside e_lo..e_hi
        e_kw, v_kw = {"ge": e_lo, "le": e_hi}, {"ge": v_lo, "le": v_hi}
        (b_lo, b_hi) = m.youngs_kpa_range
        e_what = (f"Young's modulus, kPa, judged with the others by ratios (GET /model: materials.box; at the "
                  f"nominal scale {b_lo:g}..{b_hi:g} kPa, nominal {m.nominal_youngs_kpa:g}); any value within "
                  f"{RATIO_SPAN:g} x of the nominal either way is a valid field")
        v_what = f"shear-wave speed, m/s (eq. 1), judged by ratios; {v_lo:g}..{v_hi:g} m/s is a valid field"
    else:
        e_kw, v_kw = {"ge": e_lo, "le": e_hi}, {"ge": v_lo, "le": v_hi}
        e_what = f"Young's modulus, {e_lo:g}..{e_hi:g} kPa (nominal {m.nominal_youngs_kpa:g})"
        v_what = f"shear-wave speed, {v_lo:g}..{v_hi:g} m/s (eq. 1)"
    return create_model(
        f"Material_{m.tissue}", __base__=TissueValueBase,
        youngs_kpa=(_number(e_what, **e_kw), None), shear_wave_speed_m_s=(_number(v_what, **v_kw), None),
        std_percent=(Annotated[Optional[float], Field(None, strict=True, allow_inf_nan=False, ge=0, le=100,
                                                      description=f"1-sigma, % of the value "
                                                                  f"(default {m.std_percent:g} % of E)")], None),
        std=(Annotated[Optional[float], Field(None, strict=True, allow_inf_nan=False, ge=0,
                                              description="1-sigma in the value's unit, at most the value")], None))


def materials_request_model(info: MaterialsInfo) -> type[BaseModel]:
    """The request's `materials` object: one optional field per tissue, with the declared ranges."""
    fields = {m.tissue: (Optional[_tissue_model(m, by_ratios=bool(info.by_ratios))], Field(None)) for m in info.inputs}
    return create_model("Materials", __config__=ConfigDict(extra="forbid"), **fields)


def _youngs_sigma(m: MaterialInput, value: TissueValueBase | None) -> tuple[float, float]:
    """A tissue's E (kPa) and the std of ln E, from its request value (None: nominal, the scene's std)."""
    youngs, sigma = m.nominal_youngs_kpa, sigma_ln_e(std=m.std_percent, value=100.0)
    if value is None:
        return youngs, sigma
    speed = value.shear_wave_speed_m_s is not None
    measured = value.shear_wave_speed_m_s if speed else value.youngs_kpa
    if measured is not None:
        youngs = youngs_from_shear_wave_kpa(shear_wave_speed_m_s=measured, density_kg_m3=m.density_kg_m3,
                                            poisson=m.poisson) if speed else measured
    if value.std is not None:
        sigma = sigma_ln_e(std=value.std, value=measured, shear_wave=speed)
    elif value.std_percent is not None:
        sigma = sigma_ln_e(std=value.std_percent, value=100.0, shear_wave=speed)
    return youngs, sigma


def material_vectors(info: MaterialsInfo, given: BaseModel | None) -> np.ndarray:
    """(2, m) float32: theta = ln(E / E_nominal) and sigma = std of ln E per tissue, in the graph's order.

    By ratios, theta is the box's point with the request's ratios (ratio_point); RequestProblem 422 (outside_box)
    when there is none, naming a tissue the request gave (the one over its upper bound if it gave both)."""
    out = np.zeros((2, len(info.inputs)), dtype=np.float64)
    for i, m in enumerate(info.inputs):
        youngs, sigma = _youngs_sigma(m, getattr(given, m.tissue, None) if given is not None else None)
        if not info.by_ratios:
            lo, hi = m.youngs_kpa_range
            youngs = min(max(youngs, lo), hi)  # v_s rounding stays inside
        out[:, i] = math.log(youngs / m.nominal_youngs_kpa), sigma
    if info.by_ratios and given is not None:
        lo, hi = info.log_box
        try:
            out[0] = ratio_point(out[0].tolist(), lo, hi, info.tissues)
        except OutsideBox as exc:
            named = exc.stiff if getattr(given, exc.stiff, None) is not None or getattr(given, exc.soft) is None \
                else exc.soft
            field = f"materials.{named}"
            raise RequestProblem(422, field=field, type="outside_box", message=f"{field}: {exc}") from None
    return out.astype(np.float32)


def budget_parts(manifest: ModelManifest) -> dict[str, dict]:
    """Per accuracy region, the static part of the error budget (mm, None: not measured) and what each term is
    measured against; {} for a model without material inputs."""
    info = manifest.materials
    if info is None:
        return {}
    acc, mat = manifest.accuracy, info.accuracy
    parts = {}
    for name, r in acc.regions.items():
        first = mat.regions[name].first_order_mm if mat is not None and name in mat.regions else None
        # each name says what the term is: a bound (the largest error measured) or a std (1 sigma)
        parts[name] = {"surrogate_bound_mm": r.surrogate_mm, "fe_discretisation_bound_mm": r.fe_discretisation_mm,
                       "material_first_order_bound_mm": first}
    parts["reference"] = {
        "region": "the bounds are the manifest's for this region (all_nodes for points or all nodes)",
        "surrogate_and_fe": acc.reference,
        "material_first_order": mat.reference if mat is not None else "not checked against fresh FE for this model",
        "material_std": "first-order propagation of the materials' std through du/d ln E, largest |std| at the "
                        "returned points (std_mm: per point, the std of x, y and z)",
        "total": f"the measured bounds + {STD_SIGMAS:g} x material_std_mm_max; "
                 "a term not measured counts 0 and is null"}
    return parts


_ONES3 = np.ones(3, dtype=np.float32)


def error_budget(parts: dict[str, dict], region: str | None, std: np.ndarray) -> dict:
    """The reply's error_budget for a region (None: all nodes or points) and the returned std (k, 3)."""
    static = parts.get(region) if region in parts and region != "reference" else parts["all_nodes"]
    # the largest |std| of a point: sqrt of the largest sum of squares (sqrt is monotonic), in float32 and as a
    # matrix-vector product, the cheapest of the ways tried (why: CHANGELOG, "The error budget's largest std")
    std_max = float(np.sqrt(((std * std) @ _ONES3).max())) if len(std) else 0.0
    total = sum(v for v in static.values() if v is not None) + STD_SIGMAS * std_max
    return {**static, "material_std_mm_max": std_max, "total_mm": total,
            "region": region if region in parts else "all_nodes", "measured_against": parts["reference"]}


def box(info: MaterialsInfo) -> dict:
    """GET /model's `materials.box`: the ranges as ratios E / E_nominal (the graph's box), in kPa at the nominal
    scale (the scene's E, the adipose at its nominal), and by ratios each tissue alone with the others nominal."""
    lo, hi = info.log_box
    out = {"judged_by": "ratios" if info.by_ratios else "absolute E",
           "rule": ("a request is answerable when one common factor k puts every E_i / (k E_i,nominal) inside its "
                    "ratio range; it is answered at the k nearest the nominal stiffnesses, so E x k gives the "
                    "answer of E" if info.by_ratios else
                    "each E inside its range: a tissue that carries load is not an input, so its nominal E is "
                    "absolute and E x k of the inputs is another patient"),
           "ratio_to_nominal": {}, "youngs_kpa_at_nominal_scale": {}}
    for i, m in enumerate(info.inputs):
        out["ratio_to_nominal"][m.tissue] = [math.exp(lo[i]), math.exp(hi[i])]
        out["youngs_kpa_at_nominal_scale"][m.tissue] = list(m.youngs_kpa_range)
    if info.by_ratios:  # one tissue moved, the others at their nominal E: the shifts the others allow widen its range
        out["youngs_kpa_alone"] = {}
        for i, m in enumerate(info.inputs):
            # c >= theta_j - hi_j and c <= theta_j - lo_j, with theta_j = 0
            shift_lo = max([-high for j, high in enumerate(hi) if j != i], default=0.0)
            shift_hi = min([-low for j, low in enumerate(lo) if j != i], default=0.0)
            out["youngs_kpa_alone"][m.tissue] = [m.nominal_youngs_kpa * math.exp(lo[i] + shift_lo),
                                                 m.nominal_youngs_kpa * math.exp(hi[i] + shift_hi)]
    return out


def summary(info: MaterialsInfo) -> dict:
    """GET /model's `materials`: the inputs with their ranges, units, nominal values and default std, the box as
    ratios, and the std convention (what a drawn or sent uncertainty's radius is)."""
    return {"parameter": info.parameter, "units": {"youngs_kpa": "kPa", "shear_wave_speed_m_s": "m/s",
                                                   "std_percent": "% of the value", "std": "the value's unit"},
            "inputs": [{**m.model_dump(), "shear_wave_range_m_s": list(m.shear_wave_range_m_s)} for m in info.inputs],
            "box": box(info),
            "std": {"std_mm": "1 sigma of x, y and z per point", "sigma_ln_e": "std_percent / 100 of E, "
                    "2 std_percent / 100 of a shear-wave speed (std / value in its unit)",
                    "halo_sigmas": HALO_SIGMAS, "halo": f"drawn and sent as a sphere of radius {HALO_SIGMAS:g} x "
                    f"|std_mm| (the viewer's halo; OpenIGTLink's point diameter {2 * HALO_SIGMAS:g} x |std_mm|)"},
            "accuracy": info.accuracy.model_dump() if info.accuracy is not None else None}
