"""Bearer-token auth: 401 without a token, 403 with a wrong one; health stays open; /metrics and /docs closable."""

import re

import pytest
from fastapi.testclient import TestClient

from service.app import create_app

BODY = {"displacement_mm": 5.0, "angle_deg": 2.0, "region": "markers"}


def _bearer(token: str) -> dict:
    return {"authorization": f"Bearer {token}"}


@pytest.fixture(scope="module")
def token_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("auth") / "tokens"
    path.write_text("# one token a line\nfrom-file-1\n\n  from-file-2  \n")
    return path


@pytest.fixture(scope="module")
def locked(settings, token_file):
    with TestClient(create_app(settings.model_copy(update={
            "auth_tokens": ["s3cret-a"], "auth_token_file": token_file}))) as c:
        yield c


def test_no_token_gets_401_in_the_house_format(locked):
    for r in (locked.post("/predict", json=BODY), locked.get("/model"), locked.get("/predict", headers=_bearer(""))):
        assert r.status_code == 401 and r.headers["www-authenticate"].startswith("Bearer")
        assert r.json() == {"detail": [{"field": "authorization", "type": "missing_token",
                                        "message": "authorization: send `Authorization: Bearer <token>`"}]}
    assert locked.get("/model", headers={"authorization": "Basic czNjcmV0LWE="}).status_code == 401


def test_a_wrong_token_gets_403(locked):
    for token in ("s3cret-b", "s3cret-a-and-more", "from-file"):
        r = locked.post("/predict", json=BODY, headers=_bearer(token))
        assert r.status_code == 403 and r.json()["detail"][0]["type"] == "invalid_token"


def test_tokens_from_the_setting_and_the_file_are_accepted(locked):
    for token in ("s3cret-a", "from-file-1", "from-file-2"):
        r = locked.post("/predict", json=BODY, headers=_bearer(token))
        assert r.status_code == 200 and r.json()["count"] == 8
    assert locked.get("/model", headers={"authorization": "bearer s3cret-a"}).status_code == 200  # scheme: any case


def test_health_stays_open_and_metrics_and_docs_are_closed(locked):
    assert locked.get("/healthz").status_code == 200 and locked.get("/readyz").status_code == 200
    for path in ("/metrics", "/docs", "/redoc", "/openapi.json", "/docs-static/swagger-ui.css", "/mesh"):
        assert locked.get(path).status_code == 401, path


def test_metrics_and_docs_can_be_left_open(settings):
    with TestClient(create_app(settings.model_copy(update={
            "auth_tokens": ["t"], "public_metrics": True, "public_docs": True}))) as c:
        for path in ("/metrics", "/docs", "/redoc", "/openapi.json", "/docs-static/swagger-ui.css"):
            assert c.get(path).status_code == 200, path
        assert c.get("/model").status_code == 401 and c.post("/predict", json=BODY).status_code == 401


def test_refusals_are_counted_in_metrics(locked):
    def counts():
        text = locked.get("/metrics", headers=_bearer("s3cret-a")).text
        predict = re.search(r'predict_requests_total{[^}]*status="403"[^}]*} (\S+)', text)
        model = re.search(r'http_errors_total{path="/model",status="401"} (\S+)', text)
        return float(predict.group(1)) if predict else 0.0, float(model.group(1)) if model else 0.0

    before = counts()
    locked.post("/predict", json=BODY, headers=_bearer("wrong"))
    locked.get("/model")
    assert counts() == (before[0] + 1, before[1] + 1)


def test_without_tokens_nothing_is_asked(client):
    assert client.get("/model").status_code == 200 and client.get("/metrics").status_code == 200


def test_the_estimate_stream_asks_for_the_same_tokens(locked):
    from starlette.websockets import WebSocketDisconnect

    with pytest.raises(WebSocketDisconnect) as refused:
        with locked.websocket_connect("/estimate/stream"):
            pass
    assert refused.value.code == 1008
    with locked.websocket_connect("/estimate/stream", headers={"Authorization": "Bearer s3cret-a"}) as ws:
        ws.send_json({"markers": [{"index": 0}]})
        assert ws.receive_json()["detail"][0]["field"].startswith("markers.0")
