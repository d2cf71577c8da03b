"""Prometheus counters of POST /predict: requests by target, reply format and status; latency by target."""

from __future__ import annotations

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest

LATENCY_BUCKETS = (0.0002, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.04, 0.1, 0.25, 1.0)


class Metrics:
    """One registry per app, so two apps in one process (tests) count apart."""

    content_type = CONTENT_TYPE_LATEST

    def __init__(self):
        self.registry = CollectorRegistry()
        self.requests = Counter("predict_requests", "POST /predict requests", ["region", "format", "status"],
                                registry=self.registry)
        self.latency = Histogram("predict_latency_seconds", "POST /predict handling time", ["region"],
                                 buckets=LATENCY_BUCKETS, registry=self.registry)

    def text(self) -> bytes:
        return generate_latest(self.registry)
