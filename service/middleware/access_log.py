"""The access log as JSON lines on stdout: one object per request (time, client, method, path, status, ms, bytes)."""

from __future__ import annotations

import logging
import sys
import time
from datetime import datetime, timezone

import orjson

LOGGER = "service.access"


def json_lines_logger() -> logging.Logger:
    """The access logger: each record's message is one JSON object, written alone on a line to stdout."""
    logger = logging.getLogger(LOGGER)
    if not logger.handlers:
        handler = logging.StreamHandler(sys.stdout)
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False  # not again through uvicorn's or the root logger's handlers
    return logger


class JsonAccessLog:
    """ASGI middleware: log every HTTP request once its reply is sent (status 0: the client went away first)."""

    def __init__(self, app, *, logger: logging.Logger):
        self.app, self.logger = app, logger

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        t0, status, sent = time.perf_counter(), 0, 0

        async def send_noting(message):
            nonlocal status, sent
            if message["type"] == "http.response.start":
                status = message["status"]
            elif message["type"] == "http.response.body":
                sent += len(message.get("body", b""))
            await send(message)

        try:
            await self.app(scope, receive, send_noting)
        except Exception:
            status = status or 500  # the server's error handler, outside this middleware, replies 500
            raise
        finally:
            client = scope.get("client") or ("", 0)
            self.logger.info(orjson.dumps({
                "time": datetime.now(timezone.utc).isoformat(timespec="milliseconds"),
                "client": f"{client[0]}:{client[1]}", "method": scope["method"], "path": scope["path"],
                "status": status, "ms": round((time.perf_counter() - t0) * 1e3, 3),
                "bytes": sent}).decode())
