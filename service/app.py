"""FastAPI app factory: POST /predict plus model, mesh, health and metrics endpoints."""

from __future__ import annotations

import logging
from contextlib import asynccontextmanager
from functools import partial

from fastapi import FastAPI
from fastapi.exceptions import RequestValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from . import http
from .docs import DOCS_PATHS, STATIC, add_offline_docs
from .estimate.routes import Closing, estimate_router
from .estimate.schemas import estimate_field_hints
from .igtl import igtl_server
from .info import model_info
from .middleware.access_log import JsonAccessLog, json_lines_logger
from .middleware.auth import BearerAuth
from .middleware.limits import PendingLimit, RateLimit
from .middleware.metrics import Metrics, PredictMetrics
from .model import ModelError, OutsideMesh, Predictor, check_graph, onnx_session, read_model_folder
from .predict.pipeline import Pipeline
from .predict.routes import outside_mesh, predict_router
from .predict.schemas import field_hints, predict_request_model
from .routes import HEALTH_PATHS, router
from .settings import Settings
from .viewer import viewer_router

log = logging.getLogger(__name__)


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app around one model folder; the ONNX session is opened in the lifespan."""
    settings = settings or Settings()
    # The folder is read here, once, not in the lifespan: the request model's ranges and region enum
    # come from its manifest, and FastAPI builds the OpenAPI schema from the route annotations when
    # the routes are added, before any lifespan runs. ModelError stops the start with a clear message.
    folder = read_model_folder(settings.model)
    # the session is opened here, once: a manifest that promises inputs the graph lacks would answer 500s
    session = onnx_session(folder.path / "model.onnx", threads=settings.threads)
    check_graph(folder, session)
    info = model_info(folder, settings)
    igtl = igtl_server(settings, folder, info)  # None unless settings.igtl; IgtlError for a target outside the mesh

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        predictor = Predictor(folder, session=session)
        pipeline = Pipeline.start(predictor, model=info.name, settings=settings,
                                  observe=app.state.metrics.observe_batch)
        app.state.predictor = predictor
        app.state.closing = Closing.of(predictor)  # /estimate and /plan
        app.state.pipeline = pipeline  # /predict
        log.info("decoded on the event loop when idle: %s", ", ".join(sorted(pipeline.inline)) or "nothing")
        log.info("model %s loaded: %d nodes", info.name, len(folder.nodes))
        if igtl is not None:
            igtl.start(app.state.predictor)
        yield
        if igtl is not None:
            igtl.stop()
        app.state.predictor = app.state.pipeline = app.state.closing = None
        await pipeline.stop()

    app = FastAPI(
        title="Prostate deformation service",
        version="0.1.0",
        description="Deformed prostate and surrounding tissue for a needle-guide displacement and angle, "
        f"decoded from the PCA + MLP surrogate `{info.name}` in milliseconds.",
        lifespan=lifespan,
        docs_url=None,  # add_offline_docs serves /docs and /redoc without a CDN
        redoc_url=None,
    )
    app.state.predictor = app.state.pipeline = app.state.closing = None
    app.state.info = info
    app.state.metrics = Metrics()
    app.state.field_hints = {**estimate_field_hints(info), **field_hints(info, settings.max_points)}
    app.add_exception_handler(RequestValidationError, http.invalid_request)
    app.add_exception_handler(StarletteHTTPException, http.http_problem)
    app.add_exception_handler(OutsideMesh, outside_mesh)
    app.include_router(predict_router(predict_request_model(info, settings.max_points)))
    app.include_router(estimate_router(info, settings.max_points))
    app.include_router(router)
    app.include_router(viewer_router())
    add_offline_docs(app)
    add_middleware(app, settings)
    return app


def add_middleware(app: FastAPI, settings: Settings) -> None:
    """The layers around the routes, outermost first: metrics, access log, CORS, auth, rate limit,
    the cap on /predict requests, the body limit. The outer ones see (and count) the inner ones' replies."""
    # Starlette wraps each added middleware around the ones before it: add innermost first.
    app.add_middleware(http.BodyLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(PendingLimit, max_pending=settings.max_pending)
    if settings.rate_limit > 0:
        app.add_middleware(RateLimit, rate=settings.rate_limit, burst=settings.rate_burst, exempt=HEALTH_PATHS)
    if tokens := settings.tokens():
        open_paths = HEALTH_PATHS | ({"/metrics"} if settings.public_metrics else set()) | (
            set(DOCS_PATHS) if settings.public_docs else set())
        app.add_middleware(BearerAuth, tokens=tokens, open_paths=frozenset(open_paths),
                           open_prefixes=(STATIC + "/",) if settings.public_docs else ())
    if settings.cors_origins:
        app.add_middleware(http.Cors, origins=settings.cors_origins)
    if settings.access_log == "json":
        app.add_middleware(JsonAccessLog, logger=json_lines_logger())
    app.add_middleware(PredictMetrics, metrics=app.state.metrics, served_paths=partial(served_paths, app))


def served_paths(app: FastAPI) -> frozenset[str]:
    """The paths the app answers (those in its OpenAPI schema, and the docs): the label values of error metrics."""
    return frozenset(app.openapi()["paths"]) | frozenset(DOCS_PATHS)


__all__ = ["create_app", "ModelError"]
