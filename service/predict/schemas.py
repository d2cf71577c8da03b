"""Request and reply schemas; the request's ranges and region names come from the loaded model."""

from __future__ import annotations

from enum import Enum
from typing import Annotated, Optional

from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator

from ..info import ModelInfo
from ..materials import NO_MATERIALS, materials_request_model


def _coordinate(lo: float, hi: float, axis: str):
    # strict: JSON numbers only (lax mode would take true or "5" as a number)
    return Annotated[float, Field(strict=True, allow_inf_nan=False, ge=lo, le=hi, description=f"{axis}, mm")]


class PredictRequestBase(BaseModel):
    """The fields of every PredictRequest; `predict_request_model` narrows them to the loaded model."""

    # region and points exclude each other; the schema says so, and so does the 422
    model_config = ConfigDict(extra="forbid", json_schema_extra={"not": {"required": ["region", "points"]}})

    displacement_mm: float
    angle_deg: float
    region: Optional[Enum] = None
    points: Optional[list[tuple[float, float, float]]] = None

    @model_validator(mode="after")
    def _one_target(self):
        if self.region is not None and self.points is not None:
            raise ValueError("give either region or points, not both")
        return self


def predict_request_model(info: ModelInfo, max_points: int) -> type[PredictRequestBase]:
    """A pydantic model whose ranges are the model's training envelope, so /docs and errors state them; a material
    model's request also takes `materials` (service/materials.py), with the declared ranges."""
    (d_lo, d_hi), (a_lo, a_hi), (lo, hi) = info.displacement_mm, info.angle_deg, info.bounds_mm
    Point = tuple[_coordinate(lo[0], hi[0], "x"), _coordinate(lo[1], hi[1], "y"), _coordinate(lo[2], hi[2], "z")]
    Region = Enum("Region", {name: name for name in info.regions}, type=str)
    extra = {}
    if info.materials is not None:
        extra["materials"] = (Optional[materials_request_model(info.materials)], Field(
            None, description="per tissue youngs_kpa or shear_wave_speed_m_s, optional std_percent or std; a tissue "
                              "left out is nominal with the scene's uncertainty (GET /model: materials)"))
    return create_model(
        "PredictRequest",
        __base__=PredictRequestBase,
        displacement_mm=(float, Field(ge=d_lo, le=d_hi, strict=True, allow_inf_nan=False,
                                      description=f"guide displacement into the rectal wall, {d_lo}..{d_hi} mm",
                                      examples=[5.0])),
        angle_deg=(float, Field(ge=a_lo, le=a_hi, strict=True, allow_inf_nan=False,
                                description=f"guide tilt β, {a_lo}..{a_hi} degrees", examples=[2.0])),
        # Not Optional: leaving the field out means "not given"; null is not a value the schema allows.
        region=(Region, Field(None, description="decode only this named node set (default: all nodes)")),
        points=(Annotated[list[Point], Field(min_length=1, max_length=max_points)],
                Field(None, description=f"up to {max_points} [x, y, z] reference positions in mm, inside the mesh")),
        **extra,
    )


class PredictReply(BaseModel):
    model: str
    displacement_mm: float
    angle_deg: float
    region: Optional[str] = Field(None, description="the decoded region; null for all nodes or for points")
    count: int
    positions: list[list[float]] = Field(description="deformed positions [x, y, z] in mm, in the region's node order")
    displacements: Optional[list[list[float]]] = Field(
        None, description="displacement vectors in mm; given for markers and for points")
    node_ids: Optional[list[int]] = Field(None, description="mesh node ids of the positions, for a region")
    std_mm: Optional[list[list[float]]] = Field(
        None, description="a material model's std of x, y and z per position, mm, from the materials' std (first "
                          "order; at points an upper bound: the nodes' std interpolated with |shape functions|)")
    error_budget: Optional[dict] = Field(
        None, description="a material model's error terms in mm (surrogate, FE discretisation, material first order, "
                          "the largest std, total) and what each is measured against")


def field_hints(info: ModelInfo, max_points: int) -> dict[str, str]:
    """What each request field accepts, in words, for the 422 messages."""
    (d_lo, d_hi), (a_lo, a_hi), (lo, hi) = info.displacement_mm, info.angle_deg, info.bounds_mm
    return {
        "displacement_mm": f"a finite number from {d_lo} to {d_hi} mm, the model's training envelope",
        "angle_deg": f"a finite number from {a_lo} to {a_hi} degrees, the model's training envelope",
        "region": "one of " + ", ".join(info.regions),
        "points": f"1 to {max_points} points, each [x, y, z] in mm inside the mesh, within "
                  f"{[round(v, 2) for v in lo]} to {[round(v, 2) for v in hi]}",
        "materials": NO_MATERIALS if info.materials is None else (
            ("per tissue youngs_kpa or shear_wave_speed_m_s within 1e6 x of the nominal, judged by their ratios "
             "(GET /model: materials.box), optional std_percent or std up to the value; at the nominal scale: "
             if info.materials.by_ratios else
             "per tissue youngs_kpa or shear_wave_speed_m_s inside its range, optional std_percent or std: ")
            + "; ".join(f"{m.tissue} {m.youngs_kpa_range[0]:g}..{m.youngs_kpa_range[1]:g} kPa"
                        for m in info.materials.inputs)),
    }
