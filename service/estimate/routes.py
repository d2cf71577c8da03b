"""POST /estimate (the state from tracked points), POST /plan (where to put the guide) and the estimate stream.

Thin handlers: a validated body becomes a `Problem` (fit.py) or a lesion (aim.py), the
numerics run off the event loop, the answer becomes a typed reply. `Closing` holds what both need of the model.
"""

# No `from __future__ import annotations`: FastAPI must see the request models built in estimate_router.
import json
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Request, WebSocket, WebSocketDisconnect
from pydantic import BaseModel, ValidationError
from starlette.concurrency import run_in_threadpool

from ..guide import Guide
from ..http import RequestProblem, error_responses
from ..info import ModelInfo
from ..materials import material_vectors
from ..model import OutsideMesh, Predictor
from . import aim
from .fit import Estimate, Problem, StateSpace, estimate, model_sigma_mm, point_set
from .schemas import EstimateReply, PlanReply, estimate_request_model, plan_request_model

MIN_THETA_STD = 1e-4  # a stiffness std of ln E below this counts as this (0 would be an infinite weight)


@dataclass(frozen=True)
class Closing:
    """The model as /estimate and /plan see it."""

    predictor: Predictor
    space: StateSpace
    guide: Guide
    markers: np.ndarray  # (8,) node ids of the markers region, in its order; empty when the model has none
    budget_mm: float  # the model's bound at points: surrogate + FE discretisation (+ material first order)
    name: str

    @classmethod
    def of(cls, predictor: Predictor) -> "Closing":
        m = predictor.manifest
        acc = m.accuracy.regions.get("all_nodes")
        budget = 0.0 if acc is None else acc.surrogate_mm + (acc.fe_discretisation_mm or 0.0)
        mat = m.materials.accuracy if m.materials is not None else None
        if mat is not None and "all_nodes" in mat.regions:
            budget += mat.regions["all_nodes"].first_order_mm
        markers = predictor.folder.regions.get("markers", np.zeros(0, dtype=np.int64))
        return cls(predictor, StateSpace.of(predictor), Guide.of(m), np.asarray(markers), budget, m.name)

    def stiffness_prior(self, materials: BaseModel | None) -> tuple[np.ndarray, np.ndarray]:
        """(theta, std of ln E) per tissue: the request's, or nominal with the scene's std."""
        info = self.predictor.manifest.materials
        if info is None:
            return np.zeros(0), np.zeros(0)
        vec = material_vectors(info, materials).astype(np.float64)
        return vec[0], vec[1]


def _located(closing: Closing, *, node_ids, points, field: str, n_obs: int):
    try:
        return point_set(closing.predictor, node_ids=node_ids, points=points)
    except OutsideMesh as exc:
        at = (f"points.{exc.index}.reference_mm" if exc.index < n_obs else
              field if field == "lesion_mm" else f"{field}.{exc.index - n_obs}")
        raise RequestProblem(422, field=at, type="outside_mesh",
                             message=f"{at}: {exc.point} is outside the mesh (a point must lie in a tet)") from None


def problem_of(closing: Closing, body: BaseModel) -> tuple[Problem, list[str]]:
    """The fit's problem from a validated /estimate body, and the name of each observation (markers.i, points.i)."""
    markers, points = getattr(body, "markers", None) or [], body.points or []
    if not markers and not points:
        field = "markers" if len(closing.markers) else "points"
        raise RequestProblem(422, field=field, type="missing",
                             message=f"{field}: give at least one tracked marker (markers) or point (points)")
    targets = body.targets or []
    refs = [p.reference_mm for p in points] + list(targets)
    pts = _located(closing, node_ids=closing.markers[[m.index for m in markers]], points=np.array(refs).reshape(-1, 3),
                   field="targets", n_obs=len(points))
    observed = np.array([o.position_mm for o in [*markers, *points]], dtype=np.float64)
    noise = np.array([o.std_mm for o in [*markers, *points]], dtype=np.float64)
    n = len(closing.space.names)
    mean, std = np.zeros(n), np.full(n, np.inf)
    prior = body.prior
    if prior is not None and prior.displacement_mm is not None:
        mean[0], std[0] = prior.displacement_mm.value, prior.displacement_mm.std
    if prior is not None and prior.angle_deg is not None:
        mean[1], std[1] = prior.angle_deg.value, prior.angle_deg.std
    if closing.space.n_materials and getattr(body, "stiffness_prior", True):
        theta, sigma = closing.stiffness_prior(getattr(body, "materials", None))
        mean[2:], std[2:] = theta, np.maximum(sigma, MIN_THETA_STD)
    names = [f"markers.{i}" for i in range(len(markers))] + [f"points.{i}" for i in range(len(points))]
    sigma = model_sigma_mm(closing.predictor, np.array(list(targets)).reshape(-1, 3))
    return Problem(pts, len(observed), observed, noise, mean, std, sigma), names


def estimate_reply(closing: Closing, problem: Problem, names: list[str], fit: Estimate) -> dict:
    space, std = closing.space, np.sqrt(np.diag(fit.covariance))
    state = [{"name": n, "value": float(v), "std": float(s), "at_bound": i in fit.at_bound}
             for i, (n, v, s) in enumerate(zip(space.names, fit.x, std))]
    info = closing.predictor.manifest.materials
    youngs = ({m.tissue: float(m.nominal_youngs_kpa * np.exp(t)) for m, t in zip(info.inputs, fit.x[2:])}
              if info is not None else None)
    targets = []
    for ref, pos, cov in zip(problem.points.reference[problem.n_obs:], fit.targets, fit.target_covariance):
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        targets.append({"reference_mm": ref.tolist(), "position_mm": pos.tolist(), "std_mm": sd.tolist(),
                        "model_bound_mm": closing.budget_mm,
                        "total_mm": closing.budget_mm + 2 * float(np.sqrt(max(np.linalg.eigvalsh(cov)[-1], 0.0)))})
    distance = np.linalg.norm(fit.predicted - problem.observed, axis=1)
    residuals = [{"observation": n, "predicted_mm": p.tolist(), "residual_mm": float(r), "normalised": float(z)}
                 for n, p, r, z in zip(names, fit.predicted, distance, fit.normalised)]
    return {"model": closing.name, "state": state, "youngs_kpa": youngs, "covariance": fit.covariance.tolist(),
            "targets": targets, "residuals": residuals,
            "fit": {"rms_mm": float(np.sqrt(np.mean(distance**2))), "chi2": fit.chi2, "dof": fit.dof,
                    "p_value": fit.p_value, "contradiction": fit.contradiction,
                    "outliers": [names[i] for i in fit.outliers], "iterations": fit.iterations,
                    "converged": fit.converged}}


def run_estimate(closing: Closing, body: BaseModel, x0: np.ndarray | None = None) -> tuple[dict, np.ndarray]:
    """The /estimate reply for a validated body, and the state (for a stream's next frame)."""
    problem, names = problem_of(closing, body)
    fit = estimate(closing.predictor, closing.space, problem, x0)
    return estimate_reply(closing, problem, names, fit), fit.x


def _pose(closing: Closing, a: aim.Aim) -> dict:
    return {"displacement_mm": a.displacement_mm, "angle_deg": a.angle_deg,
            "transform": closing.guide.pose(a.displacement_mm, a.angle_deg).tolist(), "lesion_mm": a.lesion_mm.tolist(),
            "miss_mm": a.miss_mm, "depth_mm": a.depth_mm}


def run_plan(closing: Closing, body: BaseModel) -> dict:
    """The /plan reply for a validated body."""
    lesion = _located(closing, node_ids=np.zeros(0, dtype=np.int64), points=np.array([body.lesion_mm]),
                      field="lesion_mm", n_obs=0)
    theta, theta_std = closing.stiffness_prior(getattr(body, "materials", None))
    result = aim.plan(closing.predictor, closing.space, closing.guide, lesion, theta=theta, theta_std=theta_std,
                      displacement_mm=body.displacement_mm)
    best = result.best
    if result.reachable:
        message = f"the needle path passes {best.miss_mm:.2f} mm from the displaced lesion (within {aim.REACH_MM} mm)"
    else:
        message = (f"unreachable: no pose in the envelope brings the needle path within {aim.REACH_MM} mm of the "
                   f"displaced lesion; the closest approach is {best.miss_mm:.2f} mm, at the pose given")
    direction = closing.guide.direction(best.angle_deg)
    return {"model": closing.name, "reachable": result.reachable, "message": message, "plan": _pose(closing, best),
            "miss_std_mm": result.miss_std_mm, "model_bound_mm": closing.budget_mm,
            "naive": _pose(closing, result.naive), "needle_direction": direction.tolist(),
            "needle_tip_mm": (closing.guide.tip_mm + best.displacement_mm * direction).tolist()}


async def get_closing(request: Request) -> Closing:
    closing = getattr(request.app.state, "closing", None)
    if closing is None:
        raise HTTPException(503, detail="model not loaded")
    return closing


ClosingDep = Annotated[Closing, Depends(get_closing)]

ERRORS = error_responses(unavailable="the model is not loaded yet")


def estimate_router(info: ModelInfo, max_points: int) -> APIRouter:
    """POST /estimate, POST /plan and WS /estimate/stream for request models built from the manifest."""
    EstimateRequest = estimate_request_model(info, max_points, int(info.summary["regions"].get("markers", 0)))
    PlanRequest = plan_request_model(info)
    router = APIRouter()

    @router.post("/estimate", response_model=EstimateReply, responses=ERRORS)
    async def estimate_endpoint(body: EstimateRequest, closing: ClosingDep):  # type: ignore[valid-type]
        """The guide's (d, beta) and the tissues' stiffnesses from tracked points, with their covariance.

        Levenberg-Marquardt on the surrogate, Laplace covariance (service/estimate.py). Each target's displaced
        position with its std; the fit's residuals, and `fit.contradiction` when the points contradict the model.
        """
        reply, _ = await run_in_threadpool(run_estimate, closing, body)
        return reply

    @router.post("/plan", response_model=PlanReply, responses=ERRORS)
    async def plan_endpoint(body: PlanRequest, closing: ClosingDep):  # type: ignore[valid-type]
        """The guide pose whose needle path passes closest to the lesion once the tissue has moved.

        `reachable` is false, with the closest approach, when no pose in the envelope comes within 2.5 mm.
        `naive` is what aiming at the undisplaced lesion misses by (service/aim.py).
        """
        return await run_in_threadpool(run_plan, closing, body)

    @router.websocket("/estimate/stream")
    async def estimate_stream(websocket: WebSocket):
        """Each text frame an /estimate body, each answer its reply (or {"detail": [...]}); a fit starts from the
        previous frame's state."""
        closing, state = websocket.app.state.closing, None
        if closing is None:  # not loaded yet: try again later
            return await websocket.close(code=1013)
        await websocket.accept()
        try:
            while True:
                text = await websocket.receive_text()
                try:
                    body = EstimateRequest.model_validate_json(text)
                    reply, state = await run_in_threadpool(run_estimate, closing, body, state)
                except ValidationError as exc:
                    reply = {"detail": [{"field": ".".join(map(str, e["loc"])) or "body", "message": e["msg"],
                                         "type": e["type"]} for e in exc.errors(include_input=False)]}
                except RequestProblem as exc:
                    reply = {"detail": [{"field": exc.field, "message": exc.detail, "type": exc.type}]}
                await websocket.send_text(json.dumps(reply))
        except WebSocketDisconnect:
            return

    return router
