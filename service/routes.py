"""The model's GET endpoints (model, mesh, health, metrics): thin handlers over the app's state, reached through typed
dependencies. POST /predict is service/predict/routes.py; /estimate and /plan are service/estimate/routes.py."""

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.responses import PlainTextResponse, Response

from .info import ModelInfo
from .middleware.metrics import Metrics
from .model import Predictor


async def get_predictor(request: Request) -> Predictor:
    predictor = request.app.state.predictor
    if predictor is None:
        raise HTTPException(503, detail="model not loaded")
    return predictor


async def get_info(request: Request) -> ModelInfo:
    return request.app.state.info


async def get_metrics(request: Request) -> Metrics:
    return request.app.state.metrics


# async: FastAPI would run a plain def dependency in the thread pool, a hop for a dict lookup
PredictorDep = Annotated[Predictor, Depends(get_predictor)]
InfoDep = Annotated[ModelInfo, Depends(get_info)]
MetricsDep = Annotated[Metrics, Depends(get_metrics)]

HEALTH_PATHS = frozenset({"/healthz", "/readyz"})  # open even when auth is on, never rate-limited

# The handlers below do no blocking work: async, so they run on the event loop without a thread hop.
router = APIRouter()


@router.get("/model")
async def model_summary(info: InfoDep) -> dict:
    """The loaded model: input envelope, regions with node counts, accuracy measured at export."""
    return info.summary


@router.get("/mesh")
async def mesh(info: InfoDep) -> Response:
    """Reference mesh for drawing: node positions (mm) and each tissue's surface triangles (node ids)."""
    return Response(info.mesh_json, media_type="application/json")


@router.get("/healthz")
async def healthz() -> dict:
    """The process is up."""
    return {"status": "ok"}


@router.get("/readyz")
async def readyz(predictor: PredictorDep, info: InfoDep) -> dict:
    """The model is loaded and answers."""
    return {"status": "ready", "model": info.name}


@router.get("/metrics", response_class=PlainTextResponse)
async def metrics(m: MetricsDep) -> Response:
    """Prometheus text: request counts by region, format and status; latency histogram per region."""
    return Response(m.text(), media_type=m.content_type)
