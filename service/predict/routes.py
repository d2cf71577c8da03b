"""POST /predict: the request parsed here (its body, Accept and ?format=), then planned, decoded and answered by
pipeline.py, or exported as a mesh file (export.py)."""

# No `from __future__ import annotations`: FastAPI must see the request model built in predict_router.
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.routing import APIRoute
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from ..http import BINARY, JsonRequest, RequestProblem, error_reply, error_responses, reply_format, require_json
from ..middleware.limits import IN_FLIGHT
from ..middleware.metrics import FORMAT, TARGET
from ..model import OutsideMesh
from .export import EXPORT_CONTENT, ExportFormat, export_response
from .pipeline import Pipeline
from .schemas import PredictReply, PredictRequestBase


async def get_pipeline(request: Request) -> Pipeline:
    pipeline = request.app.state.pipeline
    if pipeline is None:
        raise HTTPException(503, detail="model not loaded")
    return pipeline


PipelineDep = Annotated[Pipeline, Depends(get_pipeline)]  # async: a plain def would cost a thread hop


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
        `/predict` body with no query string skips FastAPI's dependency solving"). Anything else (a body that fails
        validation, ?format=, no model loaded) takes FastAPI's own path, which gives every documented error reply; the
        body is read and parsed once either way.
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


async def handle(body: PredictRequestBase, request: Request, pipeline: Pipeline,
                 export: ExportFormat | None) -> Response:
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
