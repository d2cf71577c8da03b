"""FastAPI app: POST /predict plus model, mesh, health and metrics endpoints."""


import logging
import time
from contextlib import asynccontextmanager
from typing import Annotated

import numpy as np
import orjson
from fastapi import Depends, FastAPI, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, PlainTextResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest

from contracts.model import ModelManifest

from .export import EXPORT_CONTENT, ExportFormat, export_response  # viz: ?format= (issue #13)
from .igtl import igtl_server  # viz: OpenIGTLink (issue #13)
from .model import ModelError, OutsideMesh, Predictor, read_model_folder
from .schemas import MessageReply, PredictReply, ValidationReply, predict_request_model
from .settings import Settings
from .viewer import viewer_router  # viz: GET /viewer (issue #13)

log = logging.getLogger(__name__)
BINARY = "application/octet-stream"
LATENCY_BUCKETS = (0.0002, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.04, 0.1, 0.25, 1.0)


class OrjsonResponse(JSONResponse):
    def render(self, content) -> bytes:
        return orjson.dumps(content, option=orjson.OPT_SERIALIZE_NUMPY)


class BodyLimit:
    """Reject request bodies over `max_bytes` with 413 before they are read into memory."""

    def __init__(self, app, max_bytes: int):
        self.app, self.max_bytes = app, max_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None and length.isdigit() and int(length) > self.max_bytes:
            return await self._too_large(send)
        seen = 0

        async def limited():
            nonlocal seen
            message = await receive()
            seen += len(message.get("body", b""))
            if seen > self.max_bytes:
                raise _TooLarge
            return message

        try:
            await self.app(scope, limited, send)
        except _TooLarge:
            await self._too_large(send)

    async def _too_large(self, send):
        body = orjson.dumps({"detail": f"request body over the limit of {self.max_bytes} bytes"})
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})


class _TooLarge(Exception):
    pass


def _allowed_values(manifest: ModelManifest, max_points: int, bounds) -> dict[str, str]:
    (d_lo, d_hi), (a_lo, a_hi) = manifest.envelope.displacement_mm, manifest.envelope.angle_deg
    return {
        "displacement_mm": f"a finite number from {d_lo} to {d_hi} mm, the model's training envelope",
        "angle_deg": f"a finite number from {a_lo} to {a_hi} degrees, the model's training envelope",
        "region": "one of " + ", ".join(sorted(manifest.regions)),
        "points": f"1 to {max_points} points, each [x, y, z] in mm inside the mesh, within "
                  f"{[round(v, 2) for v in bounds[0]]} to {[round(v, 2) for v in bounds[1]]}",
    }


def get_predictor(request: Request) -> Predictor:
    return request.app.state.predictor


PredictorDep = Annotated[Predictor, Depends(get_predictor)]


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app; the model folder is read once, here, so its ranges and regions shape the schema."""
    settings = settings or Settings()  # noqa: annotations below are evaluated: PredictRequest is built here
    folder = read_model_folder(settings.model)  # ModelError stops the start with a clear message
    manifest = folder.manifest
    bounds = (folder.nodes.min(axis=0).tolist(), folder.nodes.max(axis=0).tolist())
    PredictRequest = predict_request_model(manifest, settings.max_points, bounds)
    registry = CollectorRegistry()
    requests = Counter("predict_requests", "POST /predict requests", ["region", "format", "status"], registry=registry)
    latency = Histogram("predict_latency_seconds", "POST /predict handling time", ["region"],
                        buckets=LATENCY_BUCKETS, registry=registry)

    igtl = igtl_server(settings, folder)  # viz: None unless settings.igtl; IgtlError for a target outside the mesh

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        app.state.predictor = Predictor(folder, threads=settings.threads)
        log.info("model %s loaded: %d nodes", manifest.name, len(folder.nodes))
        if igtl is not None:  # viz
            igtl.start(app.state.predictor)
        yield
        if igtl is not None:  # viz
            igtl.stop()
        app.state.predictor = None

    app = FastAPI(
        title="Prostate deformation service",
        version="0.1.0",
        description="Deformed prostate and surrounding tissue for a needle-guide displacement and angle, "
        f"decoded from the PCA + MLP surrogate `{manifest.name}` in milliseconds.",
        lifespan=lifespan,
    )
    app.state.predictor = None
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    app.include_router(viewer_router())  # viz: the browser viewer and its assets
    allowed = _allowed_values(manifest, settings.max_points, bounds)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError):
        """422 naming each bad field and what it accepts; never echoes the input (it may be NaN)."""
        errors = []
        for err in exc.errors():
            loc = [str(p) for p in err["loc"] if p != "body"]
            if err["type"] == "json_invalid":
                errors.append({"field": "body", "type": err["type"],
                               "message": f"body: malformed JSON ({err.get('ctx', {}).get('error', 'cannot parse')})"})
                continue
            field = ".".join(loc) or "body"
            hint = allowed.get(loc[0] if loc else "", "")
            errors.append({"field": field, "message": f"{field}: {err['msg']}" + (f" ({hint})" if hint else ""),
                           "type": err["type"]})
        if request.url.path == "/predict":
            requests.labels("invalid", "json", "422").inc()
        return OrjsonResponse({"detail": errors}, status_code=422)

    @app.post("/predict", response_model=PredictReply, responses={
        200: {"content": {BINARY: {"schema": {"type": "string", "format": "binary"}}, **EXPORT_CONTENT},  # viz
              "description": "JSON, or with `Accept: application/octet-stream` raw little-endian float32 (count x 3); "
                             "with `?format=vtu|ply|glb` the deformed mesh as a file"},
        400: {"model": MessageReply, "description": "the body is not UTF-8 text"},
        413: {"model": MessageReply, "description": "request body too large"},
        422: {"model": ValidationReply, "description": "a field is invalid, out of the model's envelope, or outside the mesh"}})
    async def predict(body: PredictRequest, request: Request, predictor: PredictorDep,  # type: ignore[valid-type]
                      export: Annotated[ExportFormat | None, Query(alias="format", description=(  # viz: issue #13
                          "vtu (volume), ply or glb (tissue surfaces): the whole deformed mesh as a file; "
                          "with region or points, 422 (format_conflict)"))] = None):
        """Deformed positions for one guide displacement and angle.

        All nodes by default, the nodes of one `region`, or arbitrary `points` (reference
        positions, mm) interpolated inside their tet. Only what is asked for is decoded.
        With `?format=vtu|ply|glb`, the whole deformed mesh as a file (service/export.py).
        """
        if export is not None:  # viz: issue #13; the JSON and binary path below is unchanged
            reply = export_response(predictor, displacement_mm=body.displacement_mm, angle_deg=body.angle_deg,
                                    fmt=export, region=body.region, points=body.points)
            requests.labels("all", export.value, str(reply.status_code)).inc()
            return reply
        t0 = time.perf_counter()
        region = body.region.value if body.region is not None else None
        label = region or ("points" if body.points is not None else "all")
        fmt = "binary" if BINARY in request.headers.get("accept", "") else "json"
        d, a = body.displacement_mm, body.angle_deg
        node_ids = None
        if body.points is not None:
            reference = np.asarray(body.points, dtype=np.float64)
            try:
                u = predictor.at_points(d, a, reference)
            except OutsideMesh as exc:
                requests.labels(label, fmt, "422").inc()
                return OrjsonResponse({"detail": [{"field": f"points.{exc.index}", "type": "outside_mesh", "message": (
                    f"points.{exc.index}: {reference[exc.index].tolist()} is outside the mesh, which spans "
                    f"{folder.nodes.min(0).round(2).tolist()} to {folder.nodes.max(0).round(2).tolist()} mm")}]},
                    status_code=422)
            reference = reference.astype(np.float32)
        elif region is not None:
            node_ids = folder.regions[region]
            u = predictor.displacement(d, a, node_ids)
            reference = predictor.nodes32[node_ids]
        else:
            u = predictor.displacement(d, a)
            reference = predictor.nodes32
        positions = np.add(u, reference, out=u) if u.dtype == np.float32 else reference + u  # in place: no copy
        if fmt == "binary":
            # float32 arrays are little-endian on every platform onnxruntime ships for; no copy to bytes
            reply = Response(memoryview(np.ascontiguousarray(positions, dtype="<f4")), media_type=BINARY, headers={
                "X-Count": str(len(positions)), "X-Layout": "float32 little-endian, count x 3 (x, y, z) mm, deformed positions"})
        else:
            content = {"model": manifest.name, "displacement_mm": d, "angle_deg": a, "region": region,
                       "count": len(positions), "positions": positions}
            if region == "markers" or body.points is not None:
                content["displacements"] = positions - reference
            if node_ids is not None:
                content["node_ids"] = node_ids
            reply = OrjsonResponse(content)
        latency.labels(label).observe(time.perf_counter() - t0)
        requests.labels(label, fmt, "200").inc()
        return reply

    @app.get("/model")
    def model_summary():
        """The loaded model: input envelope, regions with node counts, accuracy measured at export."""
        return model_reply

    m = manifest.metrics
    model_reply = {
        "name": manifest.name, "scene": manifest.scene.model_dump(include={"name", "sha256"}),
        "mesh": manifest.mesh.model_dump(), "envelope": manifest.envelope.model_dump(), "regions": manifest.regions,
        "pca": manifest.pca.model_dump(include={"rank", "energy"}),
        "network": manifest.network.model_dump(include={"width", "depth", "activation"}),
        "fit": manifest.fit.model_dump(),
        "metrics": {"table3": m.table3_summary.model_dump(),
                    "offgrid": m.offgrid_summary.model_dump() if m.offgrid_summary else None,
                    "angle_floor_mm": m.angle_floor_mm},
        "limits": {"max_points": settings.max_points, "max_body_bytes": settings.max_body_bytes}}

    mesh_body = orjson.dumps({"nodes": folder.nodes.astype(np.float32), "tissues": manifest.mesh.tissues,
                              "surfaces": {k: v for k, v in folder.surfaces.items()}}, option=orjson.OPT_SERIALIZE_NUMPY)

    @app.get("/mesh")
    def mesh():
        """Reference mesh for drawing: node positions (mm) and each tissue's surface triangles (node ids)."""
        return Response(mesh_body, media_type="application/json")

    @app.get("/healthz")
    def healthz():
        """The process is up."""
        return {"status": "ok"}

    @app.get("/readyz")
    def readyz(request: Request):
        """The model is loaded and answers."""
        if request.app.state.predictor is None:
            raise HTTPException(503, detail="model not loaded")
        return {"status": "ready", "model": manifest.name}

    @app.get("/metrics", response_class=PlainTextResponse)
    def metrics():
        """Prometheus text: request counts by region, format and status; latency histogram per region."""
        return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)

    return app


__all__ = ["create_app", "ModelError"]
