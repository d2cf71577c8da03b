"""Request and reply schemas; the request's ranges and region names come from the loaded model."""

from __future__ import annotations

from enum import Enum
from typing import Annotated, Optional

from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator

Point = Annotated[list[Annotated[float, Field(allow_inf_nan=False)]], Field(min_length=3, max_length=3)]


class _PredictBase(BaseModel):
    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="after")
    def _one_target(self):
        if getattr(self, "region", None) is not None and getattr(self, "points", None) is not None:
            raise ValueError("give either region or points, not both")
        return self


def predict_request_model(manifest: dict, max_points: int) -> type[BaseModel]:
    """A pydantic model whose ranges are the model's training envelope, so /docs and errors state them."""
    (d_lo, d_hi), (a_lo, a_hi) = manifest["envelope"]["displacement_mm"], manifest["envelope"]["angle_deg"]
    Region = Enum("Region", {name: name for name in sorted(manifest["regions"])}, type=str)
    return create_model(
        "PredictRequest",
        __base__=_PredictBase,
        displacement_mm=(float, Field(ge=d_lo, le=d_hi, allow_inf_nan=False,
                                      description=f"guide displacement into the rectal wall, {d_lo}..{d_hi} mm",
                                      examples=[5.0])),
        angle_deg=(float, Field(ge=a_lo, le=a_hi, allow_inf_nan=False,
                                description=f"guide tilt β, {a_lo}..{a_hi} degrees", examples=[2.0])),
        region=(Optional[Region], Field(None, description="decode only this named node set (default: all nodes)")),
        points=(Optional[Annotated[list[Point], Field(min_length=1, max_length=max_points)]],
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
