"""Request and reply schemas; the request's ranges and region names come from the loaded model."""

from __future__ import annotations

from enum import Enum
from typing import Annotated, Optional

from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator

from contracts.model import ModelManifest


def _coordinate(lo: float, hi: float, axis: str):
    # strict: JSON numbers only (lax mode would take true or "5" as a number)
    return Annotated[float, Field(strict=True, allow_inf_nan=False, ge=lo, le=hi, description=f"{axis}, mm")]


class _PredictBase(BaseModel):
    # region and points exclude each other; the schema says so, and so does the 422
    model_config = ConfigDict(extra="forbid", json_schema_extra={"not": {"required": ["region", "points"]}})

    @model_validator(mode="after")
    def _one_target(self):
        if getattr(self, "region", None) is not None and getattr(self, "points", None) is not None:
            raise ValueError("give either region or points, not both")
        return self


def predict_request_model(manifest: ModelManifest, max_points: int, bounds_mm: tuple[list, list]) -> type[BaseModel]:
    """A pydantic model whose ranges are the model's training envelope, so /docs and errors state them."""
    (d_lo, d_hi), (a_lo, a_hi) = manifest.envelope.displacement_mm, manifest.envelope.angle_deg
    lo, hi = bounds_mm
    Point = tuple[_coordinate(lo[0], hi[0], "x"), _coordinate(lo[1], hi[1], "y"), _coordinate(lo[2], hi[2], "z")]
    Region = Enum("Region", {name: name for name in sorted(manifest.regions)}, type=str)
    return create_model(
        "PredictRequest",
        __base__=_PredictBase,
        displacement_mm=(float, Field(ge=d_lo, le=d_hi, strict=True, allow_inf_nan=False,
                                      description=f"guide displacement into the rectal wall, {d_lo}..{d_hi} mm",
                                      examples=[5.0])),
        angle_deg=(float, Field(ge=a_lo, le=a_hi, strict=True, allow_inf_nan=False,
                                description=f"guide tilt β, {a_lo}..{a_hi} degrees", examples=[2.0])),
        # Not Optional: leaving the field out means "not given"; null is not a value the schema allows.
        region=(Region, Field(None, description="decode only this named node set (default: all nodes)")),
        points=(Annotated[list[Point], Field(min_length=1, max_length=max_points)],
                Field(None, description=f"up to {max_points} [x, y, z] reference positions in mm, inside the mesh")),
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


class FieldError(BaseModel):
    field: str = Field(description="the offending field, dotted (points.3.0), or body")
    message: str = Field(description="what is wrong and what the field accepts")
    type: str


class ValidationReply(BaseModel):
    detail: list[FieldError]


class MessageReply(BaseModel):
    detail: str
