"""Request and reply schemas of POST /estimate and POST /plan;
ranges, marker count and tissues from the loaded model."""

from __future__ import annotations

from typing import Annotated, Optional

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, create_model
from pydantic_core import PydanticCustomError

from ..info import ModelInfo
from ..materials import materials_request_model

POSITION_LIMIT_MM = 1e4  # an observed (deformed) coordinate is a finite number inside +-this
STD_RANGE_MM = (1e-3, 100.0)  # a tracked point's noise std
PRIOR_STD_RANGE = (1e-3, 100.0)  # a guide prior's std, mm or deg


def _number(description: str, lo: float | None = None, hi: float | None = None, **more):
    # strict: JSON numbers only, as in /predict
    return Annotated[float, Field(strict=True, allow_inf_nan=False, ge=lo, le=hi, description=description, **more)]


def _json_integer(value):
    """An integer as JSON Schema has it: 6 or 6.0, never "6" or true (which lax pydantic would take)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PydanticCustomError("int_type", "Input should be a valid integer")
    return value


def _reference_point(info: ModelInfo):
    (lo, hi) = info.bounds_mm
    return tuple[tuple(_number(f"{axis}, mm (reference state)", lo[i], hi[i]) for i, axis in enumerate("xyz"))]


Observed = tuple[_number("x, mm", -POSITION_LIMIT_MM, POSITION_LIMIT_MM),
                 _number("y, mm", -POSITION_LIMIT_MM, POSITION_LIMIT_MM),
                 _number("z, mm", -POSITION_LIMIT_MM, POSITION_LIMIT_MM)]
NoiseStd = _number("1-sigma of each coordinate, mm", *STD_RANGE_MM)


def _guide_prior(info: ModelInfo) -> type[BaseModel]:
    (d_lo, d_hi), (a_lo, a_hi) = info.displacement_mm, info.angle_deg
    value = lambda lo, hi, unit, what: create_model(  # noqa: E731
        f"Prior_{what}", __config__=ConfigDict(extra="forbid"),
        value=(_number(f"{what}, {lo}..{hi} {unit}", lo, hi), ...),
        std=(_number(f"1-sigma, {unit}", *PRIOR_STD_RANGE), ...))
    return create_model(
        "GuidePrior", __config__=ConfigDict(extra="forbid"),
        displacement_mm=(value(d_lo, d_hi, "mm", "displacement"), Field(None, description="e.g. the robot's encoder")),
        angle_deg=(value(a_lo, a_hi, "deg", "angle"), Field(None, description="e.g. the robot's encoder")))


def estimate_request_model(info: ModelInfo, max_points: int, n_markers: int) -> type[BaseModel]:
    """POST /estimate's body: tracked markers and/or tracked reference points, priors, targets."""
    point = _reference_point(info)
    marker = create_model(
        "MarkerObservation", __config__=ConfigDict(extra="forbid"),
        index=(Annotated[int, Field(ge=0, le=max(n_markers - 1, 0),
                                    description=f"which of the model's {n_markers} markers (region markers' order)"),
                         BeforeValidator(_json_integer)], ...),
        position_mm=(Observed, Field(description="its observed (deformed) position, mm")),
        std_mm=(NoiseStd, ...))
    tracked = create_model(
        "PointObservation", __config__=ConfigDict(extra="forbid"),
        reference_mm=(point,
                      Field(description="the tracked point's reference (undeformed) position, mm, inside the mesh")),
        position_mm=(Observed, Field(description="its observed (deformed) position, mm")),
        std_mm=(NoiseStd, ...))
    fields = {}
    if n_markers:
        fields["markers"] = (Annotated[list[marker], Field(min_length=1, max_length=max_points)], Field(
            None, description="tracked markers, each observed with its noise std"))
    fields["points"] = (Annotated[list[tracked], Field(min_length=1, max_length=max_points)], Field(
        None, description="tracked points given by their reference position, each observed with its noise std"))
    fields["prior"] = (_guide_prior(info), Field(None, description="a prior on the guide's displacement and angle"))
    if info.materials is not None:
        fields["materials"] = (Optional[materials_request_model(info.materials)], Field(
            None, description="the stiffness prior per tissue, as in /predict (a tissue left out: nominal E with the "
                              "scene's std)"))
        fields["stiffness_prior"] = (bool, Field(True, strict=True, description=(
            "false: the stiffnesses from the tracked points alone, inside their declared ranges")))
    fields["targets"] = (Annotated[list[point], Field(min_length=1, max_length=max_points)], Field(
        None, description="lesions: reference positions, mm, inside the mesh, whose displaced position to predict"))
    required = [{"required": ["markers"]}, {"required": ["points"]}] if n_markers else [{"required": ["points"]}]
    return create_model("EstimateRequest", __config__=ConfigDict(extra="forbid", json_schema_extra={"anyOf": required}),
                        **fields)


def plan_request_model(info: ModelInfo) -> type[BaseModel]:
    """POST /plan's body: a lesion, optionally the push the clinician wants and (a material model) the stiffnesses."""
    (d_lo, d_hi) = info.displacement_mm
    fields = {
        "lesion_mm": (_reference_point(info),
                      Field(description="the lesion's reference position, mm, inside the mesh")),
        "displacement_mm": (_number(f"the push the clinician wants, {d_lo}..{d_hi} mm (default: the best)", d_lo, d_hi),
                            Field(None)),
    }
    if info.materials is not None:
        fields["materials"] = (Optional[materials_request_model(info.materials)], Field(
            None, description="per tissue stiffness with its std, as in /predict (left out: nominal, the scene's std)"))
    return create_model("PlanRequest", __config__=ConfigDict(extra="forbid"), **fields)


class Parameter(BaseModel):
    name: str = Field(description="displacement_mm, angle_deg or ln_E_<tissue> (ln(E / E_nominal))")
    value: float
    std: float = Field(description="1-sigma from the Laplace covariance")
    at_bound: bool = Field(description="the fit ended on the envelope's or the stiffness range's bound")


class Target(BaseModel):
    reference_mm: list[float]
    position_mm: list[float] = Field(description="displaced position at the estimated state, mm")
    std_mm: list[float] = Field(description="1-sigma of x, y, z, mm: the state's posterior and the model's own error "
                                            "at the point (half its bound against its own FE)")
    model_bound_mm: float = Field(description="the model's bound at points (surrogate + FE discretisation, "
                                               "+ the material first order for a material model), mm")
    total_mm: float = Field(description="model_bound_mm + 2 x the largest std's length: a 2-sigma bound, mm")


class Fit(BaseModel):
    rms_mm: float = Field(description="root mean square distance of the observed points from the model's, mm")
    chi2: float = Field(description="sum of squared normalised residuals, points and priors")
    dof: int
    p_value: Optional[float] = Field(description="chi-square tail probability; null when dof <= 0")
    contradiction: bool = Field(description="the points contradict the model: chi2 beyond its 1 - 0.001 quantile, "
                                            "or an outlier")
    outliers: list[str] = Field(description="observations whose own residual is beyond chance (markers.i, points.i)")
    iterations: int
    converged: bool


class Residual(BaseModel):
    observation: str = Field(description="markers.i or points.i")
    predicted_mm: list[float]
    residual_mm: float = Field(description="distance from the observed position, mm")
    normalised: float = Field(description="|residual / std|^2, chi-square with 3 dof under the stated noise")


class EstimateReply(BaseModel):
    model: str
    state: list[Parameter]
    youngs_kpa: Optional[dict[str, float]] = Field(None, description="a material model's estimated E per tissue")
    covariance: list[list[float]] = Field(description="of the state, in `state`'s order")
    targets: list[Target]
    fit: Fit
    residuals: list[Residual]


class Pose(BaseModel):
    displacement_mm: float
    angle_deg: float
    transform: list[list[float]] = Field(description="4x4 NeedleGuide transform (service/guide.py)")
    lesion_mm: list[float] = Field(description="the lesion's displaced position at this pose, mm")
    miss_mm: float = Field(description="distance from the displaced lesion to the needle path, mm")
    depth_mm: float = Field(description="needle insertion past the pushed tip to the closest approach, mm")


class PlanReply(BaseModel):
    model: str
    reachable: bool = Field(description="miss_mm <= 2.5 mm (the clinical target)")
    message: str
    plan: Pose = Field(description="the pose whose needle path passes closest (when unreachable: the closest approach)")
    miss_std_mm: float = Field(description="1-sigma of the miss from the stiffnesses' std (0 without material inputs)")
    model_bound_mm: float = Field(description="the model's bound at points, mm, on top of miss_std_mm")
    naive: Pose = Field(description="aiming at the undisplaced lesion with the same push")
    needle_tip_mm: list[float] = Field(description="the guide tip after the push: where the needle path starts")
    needle_direction: list[float] = Field(description="unit direction of the needle path")


def estimate_field_hints(info: ModelInfo) -> dict[str, str]:
    """What the /estimate and /plan fields accept, in words, for the 422 messages (the /predict hints win on shared
    names: displacement_mm, points, materials)."""
    (d_lo, d_hi), (a_lo, a_hi), (lo, hi) = info.displacement_mm, info.angle_deg, info.bounds_mm
    box = f"within {[round(v, 2) for v in lo]} to {[round(v, 2) for v in hi]}"
    n = int(info.summary["regions"].get("markers", 0))
    observed = (f"position_mm [x, y, z] finite, std_mm {STD_RANGE_MM[0]:g}..{STD_RANGE_MM[1]:g} mm")
    return {
        "markers": f"a list of {{index 0..{max(n - 1, 0)}, {observed}}}",
        "prior": f"{{displacement_mm: {{value {d_lo}..{d_hi}, std}}, angle_deg: {{value {a_lo}..{a_hi}, std}}}}, "
                 f"std {PRIOR_STD_RANGE[0]:g}..{PRIOR_STD_RANGE[1]:g}",
        "stiffness_prior": "true or false",
        "targets": f"a list of [x, y, z] reference positions in mm inside the mesh, {box}",
        "lesion_mm": f"[x, y, z], a reference position in mm inside the mesh, {box}",
    }
