"""FastAPI app factory: POST /predict plus model, mesh, health and metrics endpoints."""

from __future__ import annotations

import logging
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.exceptions import RequestValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from . import http
from .docs import add_offline_docs
from .igtl import igtl_server
from .info import model_info
from .metrics import Metrics, PredictMetrics
from .model import ModelError, OutsideMesh, Predictor, read_model_folder
from .routes import predict_router, router
from .schemas import field_hints, predict_request_model
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
    info = model_info(folder, settings)
    igtl = igtl_server(settings, folder)  # None unless settings.igtl; IgtlError for a target outside the mesh

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        app.state.predictor = Predictor(folder, threads=settings.threads)
        log.info("model %s loaded: %d nodes", info.name, len(folder.nodes))
        if igtl is not None:
            igtl.start(app.state.predictor)
        yield
        if igtl is not None:
            igtl.stop()
        app.state.predictor = None

    app = FastAPI(
        title="Prostate deformation service",
        version="0.1.0",
        description="Deformed prostate and surrounding tissue for a needle-guide displacement and angle, "
        f"decoded from the PCA + MLP surrogate `{info.name}` in milliseconds.",
        lifespan=lifespan,
        docs_url=None,  # add_offline_docs serves /docs and /redoc without a CDN
        redoc_url=None,
    )
    app.state.predictor = None
    app.state.info = info
    app.state.metrics = Metrics()
    app.state.field_hints = field_hints(info, settings.max_points)
    app.add_middleware(http.BodyLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(PredictMetrics, metrics=app.state.metrics)  # outside BodyLimit: counts its 413s too
    app.add_exception_handler(RequestValidationError, http.invalid_request)
    app.add_exception_handler(StarletteHTTPException, http.http_problem)
    app.add_exception_handler(OutsideMesh, http.outside_mesh)
    app.include_router(predict_router(predict_request_model(info, settings.max_points)))
    app.include_router(router)
    app.include_router(viewer_router())
    add_offline_docs(app)
    return app


__all__ = ["create_app", "ModelError"]
