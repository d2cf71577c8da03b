"""The endpoints: thin handlers over the app's state, reached through typed dependencies; POST /predict parses its
body and request here, and service/pipeline.py plans, decodes and replies."""

# No `from __future__ import annotations`: FastAPI must see the request model built in predict_router.
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.routing import APIRoute
from fastapi.responses import PlainTextResponse, Response
from starlette.concurrency import run_in_threadpool

from .export import EXPORT_CONTENT, ExportFormat, export_response
from .http import BINARY, JsonRequest, RequestProblem, error_reply, reply_format, require_json
from .info import ModelInfo
from .limits import IN_FLIGHT
from .metrics import FORMAT, TARGET, Metrics
from .model import OutsideMesh, Predictor
from .pipeline import Pipeline
from .schemas import PredictReply, PredictRequestBase, error_responses


async def get_predictor(request: Request) -> Predictor:
    predictor = request.app.state.predictor
    if predictor is None:
        raise HTTPException(503, detail="model not loaded")
    return predictor


async def get_pipeline(request: Request) -> Pipeline:
    pipeline = request.app.state.pipeline
    if pipeline is None:
        raise HTTPException(503, detail="model not loaded")
    return pipeline


async def get_info(request: Request) -> ModelInfo:
    return request.app.state.info


async def get_metrics(request: Request) -> Metrics:
    return request.app.state.metrics


# async: FastAPI would run a plain def dependency in the thread pool, a hop for a dict lookup
PredictorDep = Annotated[Predictor, Depends(get_predictor)]
InfoDep = Annotated[ModelInfo, Depends(get_info)]
MetricsDep = Annotated[Metrics, Depends(get_metrics)]
PipelineDep = Annotated[Pipeline, Depends(get_pipeline)]

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


async def outside_mesh(request: Request, exc: OutsideMesh) -> Response:
    """422 for a point that lies in no tet (the rectal lumen is a hole in the mesh)."""
    field, hint = f"points.{exc.index}", request.app.state.field_hints["points"]
    return error_reply(422, [(field, f"{field}: {exc.point} is outside the mesh ({hint})", "outside_mesh")])


PREDICT_RESPONSES = {
    200: {"content": {BINARY: {"schema": {"type": "string", "format": "binary"}}, **EXPORT_CONTENT},
          "description": "JSON, or raw little-endian float32 (count x 3) when the Accept header prefers "
                         "`application/octet-stream` (a strictly higher q than JSON); "
                         "with `?format=vtu|ply|glb` the deformed mesh as a file"},
    **error_responses(unavailable="overloaded (too many requests in the service); see Retry-After", negotiates=True),
}


def predict_router(PredictRequest: type[PredictRequestBase]) -> APIRouter:
    """POST /predict for a request model built from the loaded model's manifest.

    A closure because FastAPI reads the body's type from the handler's annotation, and that type
    (its ranges, its region enum) exists only once the model folder is read.
    """

    class PredictRoute(APIRoute):
        """A body that must be application/json (415 otherwise, before it is read), parsed once by orjson.

        With `direct` (the default), a body that validates and a request with no query string go straight to
        `handle`: FastAPI's dependency solving costs more than a markers decode (why: CHANGELOG, "A valid
        `/predict` body with no query string skips FastAPI's dependency solving"). Anything else (a body that fails validation, ?format=, no model loaded) takes
        FastAPI's own path, which gives every documented error reply; the body is read and parsed once either way.
        """

        direct = True

        def get_route_handler(self):
            fastapi_handler = super().get_route_handler()

            async def predict_handler(request: Request) -> Response:
                require_json(request.headers.get("content-type"))
                request = JsonRequest(request.scope, request.receive)
                pipeline = request.app.state.pipeline
                if self.direct and not request.scope["query_string"] and pipeline is not None:
                    try:
                        body = PredictRequest.model_validate(await request.json())
                    except (ValueError, RequestProblem):  # pydantic's ValidationError, malformed JSON, not UTF-8
                        pass
                    else:
                        return await handle(body, request, pipeline, None)
                return await fastapi_handler(request)

            return predict_handler

    predict_routes = APIRouter(route_class=PredictRoute)

    @predict_routes.post("/predict", response_model=PredictReply, responses=PREDICT_RESPONSES)
    async def predict_endpoint(body: PredictRequest, request: Request, pipeline: PipelineDep,  # type: ignore[valid-type]
                               export: Annotated[ExportFormat | None, Query(alias="format", description=(
                                   "vtu (volume), ply or glb (tissue surfaces): the whole deformed mesh as a file; "
                                   "with region or points, 422 (format_conflict)"))] = None):
        """Deformed positions for one guide displacement and angle.

        All nodes by default, the nodes of one `region`, or arbitrary `points` (reference
        positions, mm) interpolated inside their tet. Only what is asked for is decoded.
        With `?format=vtu|ply|glb`, the whole deformed mesh as a file (service/export.py).
        """
        return await handle(body, request, pipeline, export)

    return predict_routes


async def handle(body: PredictRequestBase, request: Request, pipeline: Pipeline, export: ExportFormat | None) -> Response:
    """POST /predict for a validated body: the deformed positions (pipeline.py), or with `export` the mesh as a file."""
    target = body.region.value if body.region is not None else ("points" if body.points is not None else "all")
    state = request.scope.setdefault("state", {})  # for the metrics middleware, which counts the reply
    state[TARGET] = target
    if export is not None and getattr(body, "materials", None) is not None:
        raise RequestProblem(422, field="materials", type="format_conflict",
                             message="materials: ?format= exports the nominal materials' mesh; leave materials out")
    if export is not None:
        state[FORMAT] = export.value
        region = body.region.value if body.region is not None else None
        return await run_in_threadpool(export_response, pipeline.predictor, displacement_mm=body.displacement_mm,
                                       angle_deg=body.angle_deg, fmt=export, region=region, points=body.points)
    fmt = state[FORMAT] = reply_format(request.headers.get("accept"))
    return await pipeline.respond(body, fmt, alone=state.get(IN_FLIGHT, 1) <= 1)
