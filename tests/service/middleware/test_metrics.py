"""GET /metrics counts every POST /predict reply, whichever layer produced it."""

import re

import pytest
from fastapi.testclient import TestClient

from service.middleware.metrics import Metrics, PredictMetrics


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
    # no lifespan
    client = TestClient(PredictMetrics(app, metrics=metrics, served_paths=frozenset), raise_server_exceptions=False)
    client.post("/predict", content=b"{}")
    client.get("/healthz")  # another path: not counted
    text = metrics.text().decode()
    assert _count(text, str(status)) == 1


def test_error_replies_of_other_paths_are_counted_by_path_and_status(client):
    def count(path, status):
        found = re.search(rf'http_errors_total{{path="{path}",status="{status}"}} (\S+)', client.get("/metrics").text)
        return float(found.group(1)) if found else 0.0

    before = count("/model", 405), count("other", 404)
    client.post("/model")
    client.get("/no-such-path-1")
    client.get("/no-such-path-2")  # every unserved path shares one label
    assert (count("/model", 405), count("other", 404)) == (before[0] + 1, before[1] + 2)
