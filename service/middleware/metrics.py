"""Prometheus metrics: POST /predict replies by target, format and status, its latency, batch queue time and
batch size; error replies of every other path by path and status."""

from __future__ import annotations

import os
import time
from typing import Callable

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.multiprocess import MultiProcessCollector

# Set by `python -m service` for more than one worker: each worker writes its values there, and
# /metrics, whichever worker answers, reports the sum over all of them (prometheus_client's multiprocess mode).
MULTIPROCESS_DIR = "PROMETHEUS_MULTIPROC_DIR"

LATENCY_BUCKETS = (0.0002, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.04, 0.1, 0.25, 1.0)
QUEUE_BUCKETS = (0.00005, 0.0001, 0.00025, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25)
BATCH_BUCKETS = (1, 2, 4, 8, 16, 32, 64, 128, 256)
OTHER_PATH = "other"  # the path label of a reply to a path the app does not serve: label values stay bounded
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
        self.queue = Histogram("predict_queue_seconds", "time a /predict request waits for its batch to start",
                               buckets=QUEUE_BUCKETS, registry=self.registry)
        self.batch = Histogram("predict_batch_size", "requests decoded together in one batch",
                               buckets=BATCH_BUCKETS, registry=self.registry)
        self.errors = Counter("http_errors", "error replies (4xx, 5xx) of paths other than /predict",
                              ["path", "status"], registry=self.registry)

    def observe_batch(self, queue_seconds: list[float], size: int) -> None:
        for seconds in queue_seconds:
            self.queue.observe(seconds)
        self.batch.observe(size)

    def observe(self, *, target: str, fmt: str, status: int, seconds: float) -> None:
        self.requests.labels(target, fmt, str(status)).inc()
        self.latency.labels(target).observe(seconds)

    def text(self) -> bytes:
        if os.environ.get(MULTIPROCESS_DIR):
            merged = CollectorRegistry()
            MultiProcessCollector(merged)
            return generate_latest(merged)
        return generate_latest(self.registry)


class PredictMetrics:
    """ASGI middleware: count every reply to `path`, whichever layer sent it (auth's 401 and 403, the
    rate limit's 429, the cap's 503, the body limit's 413, a 415, 422 or 406 from the app, a 500),
    labelled with the target and format the handler recorded in request.state ("invalid" and "json",
    the error format, when it never got that far). Error replies of other paths are counted by path
    (one of `served_paths()`, read at the first error, else "other") and status."""

    def __init__(self, app, *, metrics: Metrics, served_paths: Callable[[], frozenset[str]], path: str = "/predict"):
        self.app, self.metrics, self.path, self.served_paths = app, metrics, path, served_paths
        self._served: frozenset[str] | None = None

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
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
            if scope["path"] == self.path:
                self.metrics.observe(target=state.get(TARGET, "invalid"), fmt=state.get(FORMAT, "json"),
                                     status=status, seconds=time.perf_counter() - t0)
            elif status >= 400:
                self._served = self._served if self._served is not None else self.served_paths()
                path = scope["path"] if scope["path"] in self._served else OTHER_PATH
                self.metrics.errors.labels(path, str(status)).inc()
