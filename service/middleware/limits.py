"""Admission: a per-client rate limit (429 with Retry-After) and a cap on /predict requests in the service (503)."""

from __future__ import annotations

import math
import time

from ..http import error_reply
from .auth import CLIENT

IN_FLIGHT = "predict_in_flight"  # request.state key: /predict requests in the service when this one arrived
MAX_CLIENTS = 10_000  # buckets kept; beyond this, the full (idle) ones are dropped


class RateLimit:
    """ASGI middleware: a token bucket per client (its bearer token when auth is on, else its address).

    A client may send `burst` requests at once and `rate` a second after that; a request over the
    limit gets 429 with Retry-After, the whole seconds until the bucket holds a request again.
    """

    def __init__(self, app, *, rate: float, burst: int, exempt: frozenset[str] = frozenset()):
        self.app, self.rate, self.burst, self.exempt = app, rate, burst, exempt
        self.buckets: dict[str, tuple[float, float]] = {}  # client -> (tokens, time of the last update)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["path"] in self.exempt:
            return await self.app(scope, receive, send)
        client = scope.get("state", {}).get(CLIENT) or (scope.get("client") or ("unknown",))[0]
        wait_s = self._take(client, time.monotonic())
        if wait_s > 0:
            reply = error_reply(429, [("request", f"rate limit: {self.rate:g} requests a second per client, "
                                       f"{self.burst} at once; retry in {wait_s:.2f} s", "rate_limited")],
                                headers={"Retry-After": str(max(1, math.ceil(wait_s)))})
            return await reply(scope, receive, send)
        await self.app(scope, receive, send)

    def _take(self, client: str, now: float) -> float:
        """Take one request from the client's bucket: 0 if it had one, else the seconds until it will."""
        tokens, then = self.buckets.get(client, (float(self.burst), now))
        tokens = min(float(self.burst), tokens + (now - then) * self.rate)
        if tokens >= 1.0:
            if client not in self.buckets and len(self.buckets) >= MAX_CLIENTS:
                self._forget_idle(now)
            self.buckets[client] = (tokens - 1.0, now)
            return 0.0
        self.buckets[client] = (tokens, now)
        return (1.0 - tokens) / self.rate

    def _forget_idle(self, now: float) -> None:
        """Drop the buckets that have refilled: forgetting them changes no answer."""
        full_after_s = self.burst / self.rate
        self.buckets = {c: (t, then) for c, (t, then) in self.buckets.items() if now - then < full_after_s}


class PendingLimit:
    """ASGI middleware: at most `max_pending` requests to `path` in the service at once; more get 503.

    This bounds every queue behind it (the batch queue, the thread pool's waiters): an overloaded
    service says so at once, with Retry-After, instead of letting the wait grow without end.
    """

    def __init__(self, app, *, max_pending: int, path: str = "/predict"):
        self.app, self.max_pending, self.path = app, max_pending, path
        self.pending = 0

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["path"] != self.path:
            return await self.app(scope, receive, send)
        if self.pending >= self.max_pending:
            reply = error_reply(503, [("request", f"overloaded: {self.max_pending} requests are in the service "
                                       "already; retry shortly", "overloaded")], headers={"Retry-After": "1"})
            return await reply(scope, receive, send)
        self.pending += 1
        scope.setdefault("state", {})[IN_FLIGHT] = self.pending  # this one included: 1 means it is alone
        try:
            await self.app(scope, receive, send)
        finally:
            self.pending -= 1
