"""POST /estimate and POST /plan over OpenIGTLink: tracked POINTs in; the estimate and the plan out.

The numbers are the routes': a message becomes the route's request body, validated by the same request model (the
std's range, the mesh's box), and runs through the same function (service/estimate/routes.py). Only the transport
differs:

    TrackedPoints   a point named marker_k is the model's marker k (1-based, as DeformedPoints names them), any other
                    name a tracked point whose reference position a TrackedReferences message gave. Its diameter is
                    the sphere of radius HALO_SIGMAS |std| (contracts.materials; the one convention, both ways), the
                    noise taken as isotropic: std_mm per coordinate = diameter / (2 HALO_SIGMAS sqrt(3)).
    EstimatedGuide  the estimated (d, beta) as a NeedleGuide pose (Guide.pose).
    EstimatedLesions each lesion at its estimated position, diameter 2 HALO_SIGMAS |std|: the std of /estimate's
                    targets (the state's posterior and the model's own error there).
    PlannedMiss     the lesion where the tissue carries it at the planned pose (diameter 2 HALO_SIGMAS x the miss's
                    std), then the needle path's closest point to it, T + (d + s) a(beta): their distance is the miss.
    PlannedGuide    the planned pose; sent only when the path passes within aim.REACH_MM, so that nothing drives a
                    guide to a pose that misses (PlanReport says so, with the closest approach, as /plan does).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pyigtl
from pydantic import BaseModel, ValidationError

from ..estimate.routes import Closing
from ..estimate.schemas import estimate_request_model, plan_request_model
from ..info import ModelInfo
from .devices import (DIAMETER_PER_STD, ESTIMATE_REPORT_NAME, ESTIMATED_GUIDE_NAME, ESTIMATED_LESIONS_NAME,
                      PLAN_REPORT_NAME, PLANNED_GUIDE_NAME, PLANNED_MISS_NAME, REFERENCES_NAME)
from .points import LESION_RGBA

NEEDLE_RGBA = (80, 200, 80, 255)
ISOTROPIC = math.sqrt(3.0)  # |std| of an isotropic per-coordinate std s is sqrt(3) s


class Unusable(ValueError):
    """A message that cannot become a request; the message says which point and why."""


@dataclass(frozen=True)
class RequestModels:
    """The /estimate and /plan request models of the served model, as the routes build them."""

    estimate: type[BaseModel]
    plan: type[BaseModel]

    @classmethod
    def of(cls, info: ModelInfo) -> RequestModels:
        n_markers = int(info.summary["regions"].get("markers", 0))
        return cls(estimate_request_model(info, info.summary["limits"]["max_points"], n_markers),
                   plan_request_model(info))


def tracked_body(message, *, markers: list[str], references: dict[str, np.ndarray]) -> tuple[dict, list[str]]:
    """/estimate's `markers` and `points` from a TrackedPoints message, and each observation's point name in the
    route's order (markers, then points)."""
    index = {name: i for i, name in enumerate(markers)}
    observed, tracked, seen = [], [], set()
    for name, position, diameter in zip(message.names, message.positions, message.diameters):
        if name in seen:
            raise Unusable(f"{name!r} twice")
        seen.add(name)
        if not diameter > 0:
            raise Unusable(f"{name!r} has diameter {diameter:g}: send {DIAMETER_PER_STD:g} |std| (the 2-sigma sphere; "
                           f"a per-axis std s is |std| = {ISOTROPIC:.3f} s)")
        std = float(diameter) / (DIAMETER_PER_STD * ISOTROPIC)
        at = [float(v) for v in position]
        if name in index:
            observed.append((name, {"index": index[name], "position_mm": at, "std_mm": std}))
        elif name in references:
            tracked.append((name, {"reference_mm": references[name].tolist(), "position_mm": at, "std_mm": std}))
        else:
            known = f"{markers[0]}..{markers[-1]} or " if markers else ""
            raise Unusable(f"{name!r} is no tracked point: name one {known}a {REFERENCES_NAME} point")
    body = {**({"markers": [o for _, o in observed]} if observed else {}),
            **({"points": [o for _, o in tracked]} if tracked else {})}
    return body, [n for n, _ in observed] + [n for n, _ in tracked]


def field_name(loc: tuple, names: list[str], n_markers: int, lesions: list[str]) -> str:
    """A request field's location in the message's terms: the point's name for markers.i, points.i and targets.i."""
    head, i, rest = (loc[0] if loc else None), (loc[1] if len(loc) > 1 else None), loc[2:]
    if head in ("markers", "points") and isinstance(i, int):
        where = repr(names[i + (n_markers if head == "points" else 0)])
    elif head == "targets" and isinstance(i, int) and i < len(lesions):
        where = f"lesion {lesions[i]!r}"
    else:
        return ".".join(map(str, loc)) or "body"
    return " ".join([where, *map(str, rest)])


def refusal(device: str, exc: ValidationError, names: list[str], n_markers: int, lesions: list[str]) -> str:
    err = exc.errors(include_input=False)[0]
    return f"refused {device}: {field_name(tuple(err['loc']), names, n_markers, lesions)}: {err['msg']}"


def estimate_messages(closing: Closing, reply: dict, *, names: list[str], n_markers: int, lesions: list[str],
                      timestamp) -> list:
    """TRANSFORM EstimatedGuide, POINT EstimatedLesions (when there are lesions) and STRING EstimateReport."""
    state = {p["name"]: p["value"] for p in reply["state"]}
    out = [pyigtl.TransformMessage(closing.guide.pose(state["displacement_mm"], state["angle_deg"]),
                                   device_name=ESTIMATED_GUIDE_NAME, timestamp=timestamp)]
    targets = reply["targets"]
    if targets:
        sigma = [float(np.linalg.norm(t["std_mm"])) for t in targets]
        out.append(pyigtl.PointMessage(
            positions=np.array([t["position_mm"] for t in targets]), names=lesions,
            rgba_colors=[LESION_RGBA] * len(targets),
            groups="lesions", diameters=[DIAMETER_PER_STD * s for s in sigma], device_name=ESTIMATED_LESIONS_NAME,
            timestamp=timestamp))
    route_names = [f"markers.{i}" for i in range(n_markers)] + [f"points.{j}" for j in range(len(names) - n_markers)]
    renamed = dict(zip(route_names, names))
    fit = {**reply["fit"], "outliers": [renamed[o] for o in reply["fit"]["outliers"]]}
    report = {"model": reply["model"], "state": reply["state"], "youngs_kpa": reply["youngs_kpa"], "fit": fit,
              "lesions": {n: {"std_mm": t["std_mm"], "total_mm": t["total_mm"]} for n, t in zip(lesions, targets)}}
    out.append(pyigtl.StringMessage(json.dumps(report), device_name=ESTIMATE_REPORT_NAME, timestamp=timestamp))
    return out


def plan_lesion(message) -> tuple[str, list[float]]:
    """The one lesion of a PlanLesion message: its name (or "lesion") and reference position."""
    if len(message.positions) != 1:
        raise Unusable(f"{len(message.positions)} points: a PlanLesion message holds one lesion")
    return message.names[0] or "lesion", [float(v) for v in message.positions[0]]


def plan_messages(reply: dict, *, name: str, timestamp) -> list:
    """TRANSFORM PlannedGuide (reachable only), POINT PlannedMiss and STRING PlanReport for a /plan reply."""
    plan = reply["plan"]
    needle = np.asarray(reply["needle_tip_mm"]) + plan["depth_mm"] * np.asarray(reply["needle_direction"])
    out = [] if not reply["reachable"] else [pyigtl.TransformMessage(
        np.asarray(plan["transform"]), device_name=PLANNED_GUIDE_NAME, timestamp=timestamp)]
    out.append(pyigtl.PointMessage(
        positions=np.array([plan["lesion_mm"], needle]), names=[name, f"{name}_needle"],
        rgba_colors=[LESION_RGBA, NEEDLE_RGBA], groups=["lesion", "needle"],
        diameters=[DIAMETER_PER_STD * reply["miss_std_mm"], 0.0], device_name=PLANNED_MISS_NAME, timestamp=timestamp))
    report = {"lesion": name, "reachable": reply["reachable"], "message": reply["message"],
              **{k: plan[k] for k in ("displacement_mm", "angle_deg", "miss_mm", "depth_mm")},
              "miss_std_mm": reply["miss_std_mm"], "model_bound_mm": reply["model_bound_mm"],
              "naive": {k: reply["naive"][k] for k in ("displacement_mm", "angle_deg", "miss_mm")}}
    out.append(pyigtl.StringMessage(json.dumps(report), device_name=PLAN_REPORT_NAME, timestamp=timestamp))
    return out
