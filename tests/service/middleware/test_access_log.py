"""The JSON-lines access log: one object per request with its method, path, status, time and size."""

import json
import logging

from fastapi.testclient import TestClient

from service.middleware.access_log import JsonAccessLog
from service.app import create_app


class _Lines(logging.Handler):
    def __init__(self):
        super().__init__()
        self.lines = []

    def emit(self, record):
        self.lines.append(record.getMessage())


def test_each_request_is_one_json_line(settings, monkeypatch):
    from service import app as app_module

    logger, handler = logging.getLogger("test.access"), _Lines()
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    monkeypatch.setattr(app_module, "json_lines_logger", lambda: logger)
    with TestClient(create_app(settings.model_copy(update={"access_log": "json"}))) as c:
        c.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0, "region": "markers"})
        c.post("/predict", json={"displacement_mm": 50.0, "angle_deg": 2.0})
        c.get("/healthz")
    records = [json.loads(line) for line in handler.lines]
    assert [(r["method"], r["path"], r["status"]) for r in records] == [
        ("POST", "/predict", 200), ("POST", "/predict", 422), ("GET", "/healthz", 200)]
    assert all(set(r) == {"time", "client", "method", "path", "status", "ms", "bytes"} for r in records)
    assert records[0]["bytes"] > 100 and records[0]["ms"] > 0 and records[0]["time"].endswith("+00:00")


def test_a_crash_is_logged_as_500():
    async def crashing(scope, receive, send):
        raise RuntimeError("boom")

    logger, handler = logging.getLogger("test.access.crash"), _Lines()
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    TestClient(JsonAccessLog(crashing, logger=logger), raise_server_exceptions=False).get("/x")
    assert json.loads(handler.lines[0])["status"] == 500


def test_off_and_text_add_no_json_log(client):
    assert not any(m.cls is JsonAccessLog for m in client.app.user_middleware)
