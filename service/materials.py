"""A material model's stiffness inputs at the service: the request's `materials`, the graph's vectors, the error budget.

A request may give, per tissue the model lists (GET /model, `materials.inputs`),

    {"youngs_kpa": 70.0}  or  {"shear_wave_speed_m_s": 4.3}      (eq. 1: E = 2 (1 + nu) rho v_s^2, the
                                                                   manifest's nu and rho)
    and optionally "std_percent" (of that value) or "std" (in its unit)

inside the declared range (else 422 naming e.g. `materials.prostate.youngs_kpa`). A tissue left out is at its
nominal E with the scene's stated uncertainty (`std_percent` of E), so an old client sending only (d, beta)
gets the nominal answer. The graph takes theta = ln(E / E_nominal) and sigma = the std of ln E: std(E) / E, or
2 std(v_s) / v_s (E ~ v_s^2), to first order.

Every answer of a material model carries `std_mm` (per returned point, the std of x, y and z) and an
`error_budget`: the surrogate's and the FE discretisation's bounds and the first-order material model's error
(the manifest's accuracy, each with what it was measured against), the largest std length at the returned
points, and total_mm = the three bounds + 2 x that std.
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator

from contracts.materials import MaterialInput, MaterialsInfo
from contracts.model import ModelManifest

NO_MATERIALS = "this model takes no material inputs"
STD_SIGMAS = 2.0  # total_mm counts the material uncertainty at 2 std


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
    # the most `std` may be, given with E (kPa) or with v_s (m/s): the upper end of that value's range, so sigma
    # stays finite (a std of 1e308 gave infinite std_mm); _tissue_model sets it and says it in the schema
    std_max: ClassVar[tuple[float, float]] = (math.inf, math.inf)

    @model_validator(mode="after")
    def _one_each(self):
        if self.youngs_kpa is not None and self.shear_wave_speed_m_s is not None:
            raise ValueError("give youngs_kpa or shear_wave_speed_m_s, not both")
        if self.std_percent is not None and self.std is not None:
            raise ValueError("give std_percent or std, not both")
        if self.std is not None and self.youngs_kpa is None and self.shear_wave_speed_m_s is None:
            raise ValueError("std is in the unit of youngs_kpa or shear_wave_speed_m_s: give one of them")
        if self.std is not None:
            most, unit = (self.std_max[0], "kPa") if self.youngs_kpa is not None else (self.std_max[1], "m/s")
            if self.std > most:
                raise ValueError(f"std {self.std:g} {unit} is over {most:g} {unit}, the upper end of the value's range")
        return self


def _number(lo: float, hi: float, what: str):
    return Annotated[Optional[float], Field(None, strict=True, allow_inf_nan=False, ge=lo, le=hi, description=what)]


def _tissue_model(m: MaterialInput) -> type[TissueValueBase]:
    (e_lo, e_hi), (v_lo, v_hi) = m.youngs_kpa_range, m.shear_wave_range_m_s
    v_lo, v_hi = math.floor(v_lo * 1e4) / 1e4, math.ceil(v_hi * 1e4) / 1e4  # the E range's ends stay inside
    # std's bound in the schema as well: each `if` names the unit the std is in
    bounds = {"std_max": (e_hi, v_hi), "model_config": ConfigDict(extra="forbid", json_schema_extra={"allOf": [
        *TissueValueBase.model_config["json_schema_extra"]["allOf"],
        {"if": _given("youngs_kpa"), "then": {"properties": {"std": {"maximum": e_hi}}}},
        {"if": _given("shear_wave_speed_m_s"), "then": {"properties": {"std": {"maximum": v_hi}}}}]})}
    return create_model(
        f"Material_{m.tissue}", __base__=type(f"TissueValue_{m.tissue}", (TissueValueBase,), bounds),
        youngs_kpa=(_number(e_lo, e_hi, f"Young's modulus, {e_lo:g}..{e_hi:g} kPa (nominal {m.nominal_youngs_kpa:g})"), None),
        shear_wave_speed_m_s=(_number(v_lo, v_hi, f"shear-wave speed, {v_lo:g}..{v_hi:g} m/s (eq. 1)"), None),
        std_percent=(Annotated[Optional[float], Field(None, strict=True, allow_inf_nan=False, ge=0, le=100,
                                                      description=f"1-sigma, % of the value (default {m.std_percent:g} % of E)")], None),
        std=(Annotated[Optional[float], Field(None, strict=True, allow_inf_nan=False, ge=0,
                                              description="1-sigma in the value's unit")], None))


def materials_request_model(info: MaterialsInfo) -> type[BaseModel]:
    """The request's `materials` object: one optional field per tissue, with the declared ranges."""
    fields = {m.tissue: (Optional[_tissue_model(m)], Field(None)) for m in info.inputs}
    return create_model("Materials", __config__=ConfigDict(extra="forbid"), **fields)


def material_vectors(info: MaterialsInfo, given: BaseModel | None) -> np.ndarray:
    """(2, m) float32: theta = ln(E / E_nominal) and sigma = std of ln E per tissue, in the graph's order."""
    out = np.zeros((2, len(info.inputs)), dtype=np.float64)
    for i, m in enumerate(info.inputs):
        value = getattr(given, m.tissue, None) if given is not None else None
        youngs, sigma = m.nominal_youngs_kpa, m.std_percent / 100.0
        if value is not None and value.shear_wave_speed_m_s is not None:
            v = value.shear_wave_speed_m_s
            youngs = 2.0 * (1.0 + m.poisson) * v**2 * m.density_kg_m3 / 1e3
            if value.std is not None:
                sigma = 2.0 * value.std / v
            elif value.std_percent is not None:
                sigma = 2.0 * value.std_percent / 100.0
        elif value is not None:
            youngs = value.youngs_kpa if value.youngs_kpa is not None else youngs
            if value.std is not None:
                sigma = value.std / youngs
            elif value.std_percent is not None:
                sigma = value.std_percent / 100.0
        lo, hi = m.youngs_kpa_range
        out[:, i] = math.log(min(max(youngs, lo), hi) / m.nominal_youngs_kpa), sigma  # v_s rounding stays inside
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
        parts[name] = {"surrogate_mm": r.surrogate_mm, "fe_discretisation_mm": r.fe_discretisation_mm,
                       "material_first_order_mm": first}
    parts["reference"] = {
        "region": "the bounds are the manifest's for this region (all_nodes for points or all nodes)",
        "surrogate_and_fe": acc.reference,
        "material_first_order": mat.reference if mat is not None else "not checked against fresh FE for this model",
        "material_std": "first-order propagation of the materials' std through du/d ln E, largest |std| at the "
                        "returned points (std_mm: per point, the std of x, y and z)",
        "total": f"the measured bounds + {STD_SIGMAS:g} x material_std_mm_max; a term not measured counts 0 and is null"}
    return parts


_ONES3 = np.ones(3, dtype=np.float32)


def error_budget(parts: dict[str, dict], region: str | None, std: np.ndarray) -> dict:
    """The reply's error_budget for a region (None: all nodes or points) and the returned std (k, 3)."""
    static = parts.get(region) if region in parts and region != "reference" else parts["all_nodes"]
    # the largest |std| of a point: sqrt of the largest sum of squares (sqrt is monotonic), in float32 and as a
    # matrix-vector product: 0.008 ms at 10k nodes, against 0.16 for a float64 norm of every point (and 0.05 for einsum)
    std_max = float(np.sqrt(((std * std) @ _ONES3).max())) if len(std) else 0.0
    total = sum(v for v in static.values() if v is not None) + STD_SIGMAS * std_max
    return {**static, "material_std_mm_max": std_max, "total_mm": total,
            "region": region if region in parts else "all_nodes", "measured_against": parts["reference"]}


def summary(info: MaterialsInfo) -> dict:
    """GET /model's `materials`: the inputs with their ranges, units, nominal values and default std."""
    return {"parameter": info.parameter, "units": {"youngs_kpa": "kPa", "shear_wave_speed_m_s": "m/s",
                                                   "std_percent": "% of the value", "std": "the value's unit"},
            "inputs": [{**m.model_dump(), "shear_wave_range_m_s": list(m.shear_wave_range_m_s)} for m in info.inputs],
            "accuracy": info.accuracy.model_dump() if info.accuracy is not None else None}
