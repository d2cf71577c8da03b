"""The endpoints: thin handlers over `predict` and the app's state, reached through typed dependencies."""

# No `from __future__ import annotations`: FastAPI must see the request model built in predict_router.
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.routing import APIRoute
from fastapi.responses import PlainTextResponse, Response
from starlette.concurrency import run_in_threadpool

from .batching import Batcher, QueueFull
from .export import EXPORT_CONTENT, ExportFormat, export_response
from .http import BINARY, JsonRequest, RequestProblem, reply_format, require_json
from .info import ModelInfo
from .limits import IN_FLIGHT
from .metrics import FORMAT, TARGET, Metrics
from .model import Predictor
from .predict import Prediction, decode, finish, plan, predict
from .replies import SMALL_JSON_ROWS, ChunkedResponse, binary_reply, json_chunks, rows_of
from .schemas import ErrorReply, PredictReply, PredictRequestBase


async def get_predictor(request: Request) -> Predictor:
    predictor = request.app.state.predictor
    if predictor is None:
        raise HTTPException(503, detail="model not loaded")
    return predictor


async def get_batcher(request: Request) -> Batcher | None:
    return request.app.state.batcher


@dataclass(frozen=True)
class Serving:
    """What POST /predict needs, in one dependency (each dependency costs FastAPI some microseconds a request)."""

    predictor: Predictor
    batcher: Batcher | None  # None: batching is off
    info: ModelInfo
    inline: frozenset[str]  # batching keys decoded on the event loop when nothing else is decoding (predict.cheap_keys)


async def get_serving(request: Request) -> Serving:
    serving = request.app.state.serving
    if serving is None:
        raise HTTPException(503, detail="model not loaded")
    return serving


async def get_info(request: Request) -> ModelInfo:
    return request.app.state.info


async def get_metrics(request: Request) -> Metrics:
    return request.app.state.metrics


# async: FastAPI would run a plain def dependency in the thread pool, a hop for a dict lookup
PredictorDep = Annotated[Predictor, Depends(get_predictor)]
BatcherDep = Annotated[Batcher | None, Depends(get_batcher)]  # None: batching is off
InfoDep = Annotated[ModelInfo, Depends(get_info)]
MetricsDep = Annotated[Metrics, Depends(get_metrics)]
ServingDep = Annotated[Serving, Depends(get_serving)]

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


def answer(predictor: Predictor, request: PredictRequestBase, *, fmt: str, model: str) -> Response:
    """The prediction for a request as JSON, or as raw little-endian float32 positions (count x 3)."""
    return reply(request, predict(predictor, request), fmt=fmt, model=model)


def reply(request: PredictRequestBase, prediction: Prediction, *, fmt: str, model: str) -> Response:
    """A prediction as JSON, or as raw little-endian float32 positions (count x 3); large JSON in pieces
    (service/replies.py): call it off the event loop unless `small_reply` says it is cheap."""
    if fmt == "binary":
        response = binary_reply(prediction.positions)
        if prediction.budget is not None:  # a material model: the largest 1-sigma length at the returned points
            response.headers["X-Std-Max-Mm"] = f"{prediction.budget['material_std_mm_max']:.6g}"
        return response
    scalars = {"model": model, "displacement_mm": request.displacement_mm, "angle_deg": request.angle_deg,
               "region": prediction.region, "count": len(prediction.positions)}
    if prediction.budget is not None:
        scalars["error_budget"] = prediction.budget
    return ChunkedResponse(json_chunks(scalars, reply_arrays(prediction)))


def reply_arrays(prediction: Prediction) -> dict[str, np.ndarray]:
    arrays = {"positions": prediction.positions}
    if prediction.displacements is not None:
        arrays["displacements"] = prediction.displacements
    if prediction.node_ids is not None:
        arrays["node_ids"] = prediction.node_ids
    if prediction.std is not None:
        arrays["std_mm"] = prediction.std
    return arrays


def small_reply(prediction: Prediction, fmt: str) -> bool:
    """Whether the reply costs so little to build that a thread hop would cost more: binary (no copy, no work)
    or JSON of a few rows."""
    return fmt == "binary" or rows_of(reply_arrays(prediction)) <= SMALL_JSON_ROWS


async def respond(serving: Serving, body: PredictRequestBase, fmt: str, *, alone: bool) -> Response:
    """Decode and reply. A cheap decode (`serving.inline`) of a request that arrived `alone` (no other /predict
    in the service) runs right here on the event loop: a thread hop would cost more than it, and under load
    the batcher's lanes decode on other cores while the loop does HTTP. Everything else (locating points, decoding, large JSON)
    runs off the event loop, in the batcher's lanes or the thread pool, so it stays free for /healthz and
    other requests (onnxruntime and numpy release the GIL; replies.py offers it back while writing JSON)."""
    predictor, batcher, model = serving.predictor, serving.batcher, serving.info.name
    query = plan(predictor, body) if body.points is None else None
    if query is not None and alone and query.key in serving.inline and (batcher is None or batcher.idle):
        u, std = decode(predictor, [query], query.nodes)
        prediction = finish(predictor, query, u[0], None if std is None else std[0])
    elif batcher is None:
        return await run_in_threadpool(answer, predictor, body, fmt=fmt, model=model)
    else:
        query = query or await run_in_threadpool(plan, predictor, body)
        try:
            prediction = await batcher.submit(query)  # decoded with whatever else waits for the same nodes
        except QueueFull as exc:
            raise RequestProblem(503, field="request", type="overloaded", message=f"overloaded: {exc}",
                                 headers={"Retry-After": "1"}) from None
    if small_reply(prediction, fmt):
        return reply(body, prediction, fmt=fmt, model=model)
    return await run_in_threadpool(reply, body, prediction, fmt=fmt, model=model)


PREDICT_RESPONSES = {
    200: {"content": {BINARY: {"schema": {"type": "string", "format": "binary"}}, **EXPORT_CONTENT},
          "description": "JSON, or raw little-endian float32 (count x 3) when the Accept header prefers "
                         "`application/octet-stream` (a strictly higher q than JSON); "
                         "with `?format=vtu|ply|glb` the deformed mesh as a file"},
    400: {"model": ErrorReply, "description": "the body is not UTF-8 text"},
    406: {"model": ErrorReply, "description": "the Accept header allows neither JSON nor application/octet-stream"},
    401: {"model": ErrorReply, "description": "no bearer token (when the service requires one)"},
    403: {"model": ErrorReply, "description": "the bearer token is not accepted"},
    413: {"model": ErrorReply, "description": "request body too large"},
    415: {"model": ErrorReply, "description": "the body is not sent as application/json"},
    422: {"model": ErrorReply, "description": "a field is invalid, out of the model's envelope, or outside the mesh"},
    429: {"model": ErrorReply, "description": "over the client's rate limit; see Retry-After"},
    503: {"model": ErrorReply, "description": "overloaded (too many requests in the service); see Retry-After"},
}


def predict_router(PredictRequest: type[PredictRequestBase]) -> APIRouter:
    """POST /predict for a request model built from the loaded model's manifest.

    A closure because FastAPI reads the body's type from the handler's annotation, and that type
    (its ranges, its region enum) exists only once the model folder is read.
    """

    class PredictRoute(APIRoute):
        """A body that must be application/json (415 otherwise, before it is read), parsed once by orjson.

        With `direct` (the default), a body that validates and a request with no query string go straight to
        `handle`: FastAPI's dependency solving costs more than a markers decode (in process, 10k nodes: 0.43 ->
        0.31 ms a markers request). Anything else (a body that fails validation, ?format=, no model loaded) takes
        FastAPI's own path, which gives every documented error reply; the body is read and parsed once either way.
        """

        direct = True

        def get_route_handler(self):
            fastapi_handler = super().get_route_handler()

            async def predict_handler(request: Request) -> Response:
                require_json(request.headers.get("content-type"))
                request = JsonRequest(request.scope, request.receive)
                serving = request.app.state.serving
                if self.direct and not request.scope["query_string"] and serving is not None:
                    try:
                        body = PredictRequest.model_validate(await request.json())
                    except (ValueError, RequestProblem):  # pydantic's ValidationError, malformed JSON, not UTF-8
                        pass
                    else:
                        return await handle(body, request, serving, None)
                return await fastapi_handler(request)

            return predict_handler

    predict_routes = APIRouter(route_class=PredictRoute)

    @predict_routes.post("/predict", response_model=PredictReply, responses=PREDICT_RESPONSES)
    async def predict_endpoint(body: PredictRequest, request: Request, serving: ServingDep,  # type: ignore[valid-type]
                               export: Annotated[ExportFormat | None, Query(alias="format", description=(
                                   "vtu (volume), ply or glb (tissue surfaces): the whole deformed mesh as a file; "
                                   "with region or points, 422 (format_conflict)"))] = None):
        """Deformed positions for one guide displacement and angle.

        All nodes by default, the nodes of one `region`, or arbitrary `points` (reference
        positions, mm) interpolated inside their tet. Only what is asked for is decoded.
        With `?format=vtu|ply|glb`, the whole deformed mesh as a file (service/export.py).
        """
        return await handle(body, request, serving, export)

    return predict_routes


async def handle(body: PredictRequestBase, request: Request, serving: Serving, export: ExportFormat | None) -> Response:
    """POST /predict for a validated body: the deformed positions, or with `export` the mesh as a file."""
    target = body.region.value if body.region is not None else ("points" if body.points is not None else "all")
    state = request.scope.setdefault("state", {})  # for the metrics middleware, which counts the reply
    state[TARGET] = target
    if export is not None and getattr(body, "materials", None) is not None:
        raise RequestProblem(422, field="materials", type="format_conflict",
                             message="materials: ?format= exports the nominal materials' mesh; leave materials out")
    if export is not None:
        state[FORMAT] = export.value
        region = body.region.value if body.region is not None else None
        return await run_in_threadpool(export_response, serving.predictor, displacement_mm=body.displacement_mm,
                                       angle_deg=body.angle_deg, fmt=export, region=region, points=body.points)
    fmt = state[FORMAT] = reply_format(request.headers.get("accept"))
    return await respond(serving, body, fmt, alone=state.get(IN_FLIGHT, 1) <= 1)
