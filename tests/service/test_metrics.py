"""GET /metrics counts every POST /predict reply, whichever layer produced it."""

import re

import pytest
from fastapi.testclient import TestClient

from service.metrics import Metrics, PredictMetrics


def _count(text: str, status: str) -> float:
    found = re.findall(rf'predict_requests_total{{[^}}]*status="{status}"[^}}]*}} (\S+)', text)
    return sum(float(v) for v in found)


def test_413_and_415_replies_are_counted(client):
    before = client.get("/metrics").text
    client.post("/predict", content=b" " * (65 * 1024), headers={"content-type": "application/json"})
    client.post("/predict", content=b"{}", headers={"content-type": "text/plain"})
    after = client.get("/metrics").text
    assert _count(after, "413") == _count(before, "413") + 1
    assert _count(after, "415") == _count(before, "415") + 1


@pytest.mark.parametrize("status", [200, 400, 408, 413, 415, 422, 429, 500])
def test_the_middleware_labels_every_status_of_predict(status):
    async def app(scope, receive, send):
        await send({"type": "http.response.start", "status": status, "headers": []})
        await send({"type": "http.response.body", "body": b""})

    metrics = Metrics()
    client = TestClient(PredictMetrics(app, metrics=metrics), raise_server_exceptions=False)  # no lifespan
    client.post("/predict", content=b"{}")
    client.get("/healthz")  # another path: not counted
    text = metrics.text().decode()
    assert _count(text, str(status)) == 1
