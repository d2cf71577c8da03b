"""Prometheus counters of POST /predict: replies by target, format and status; latency by target."""

from __future__ import annotations

import time

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest

LATENCY_BUCKETS = (0.0002, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.04, 0.1, 0.25, 1.0)
# request.state keys the /predict handler sets once it knows them (the request's target and reply format)
TARGET, FORMAT = "predict_target", "predict_format"


class Metrics:
    """One registry per app, so two apps in one process (tests) count apart."""

    content_type = CONTENT_TYPE_LATEST

    def __init__(self):
        self.registry = CollectorRegistry()
        self.requests = Counter("predict_requests", "POST /predict replies", ["region", "format", "status"],
                                registry=self.registry)
        self.latency = Histogram("predict_latency_seconds", "POST /predict handling time", ["region"],
                                 buckets=LATENCY_BUCKETS, registry=self.registry)

    def observe(self, *, target: str, fmt: str, status: int, seconds: float) -> None:
        self.requests.labels(target, fmt, str(status)).inc()
        self.latency.labels(target).observe(seconds)

    def text(self) -> bytes:
        return generate_latest(self.registry)


class PredictMetrics:
    """ASGI middleware: count every reply to `path`, whichever layer sent it (the body limit's 413,
    a 415, 422 or 406 from the app, a 500), labelled with the target and format the handler recorded
    in request.state ("invalid" and "json", the error format, when it never got that far)."""

    def __init__(self, app, *, metrics: Metrics, path: str = "/predict"):
        self.app, self.metrics, self.path = app, metrics, path

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["path"] != self.path:
            return await self.app(scope, receive, send)
        state = scope.setdefault("state", {})  # the dict request.state writes to
        t0, status = time.perf_counter(), 500

        async def send_noting_status(message):
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_noting_status)
        finally:
            self.metrics.observe(target=state.get(TARGET, "invalid"), fmt=state.get(FORMAT, "json"),
                                 status=status, seconds=time.perf_counter() - t0)
