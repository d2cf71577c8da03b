"""HTTP plumbing: the Accept header, the content type, the body limit and CORS."""

import pytest

from service.http import RequestProblem, reply_format


def _predict(client, headers=None, **kw):
    return client.post("/predict", headers=headers, **kw)


@pytest.mark.parametrize(("accept", "fmt"), [
    (None, "json"),
    ("", "json"),
    ("*/*", "json"),
    ("application/json", "json"),
    ("application/octet-stream", "binary"),
    ("application/octet-stream;q=0, application/json", "json"),
    ("application/octet-stream; q=0.0, */*", "json"),
    ("application/json;q=0.5, application/octet-stream", "binary"),
    ("application/*;q=0.2, application/octet-stream;q=0.1", "json"),
    ("application/octet-stream;q=0.9, */*;q=1", "json"),
    ("APPLICATION/OCTET-STREAM", "binary"),
    ("text/html, application/octet-stream;q=0.5", "binary"),
])
def test_json_unless_binary_has_a_strictly_higher_q(accept, fmt):
    assert reply_format(accept) == fmt


@pytest.mark.parametrize("accept", ["text/html", "application/json;q=0, application/octet-stream;q=0", "image/*",
                                    "application/octet-stream;q=0"])
def test_neither_format_acceptable_is_406(accept):
    with pytest.raises(RequestProblem) as err:
        reply_format(accept)
    assert err.value.status_code == 406 and "application/json" in err.value.detail


def test_q_zero_for_binary_gets_json_through_the_api(client):
    r = _predict(client, json={"displacement_mm": 5.0, "angle_deg": 2.0, "region": "markers"},
                 headers={"accept": "application/octet-stream;q=0, application/json"})
    assert r.status_code == 200 and r.headers["content-type"] == "application/json" and r.json()["count"] == 8


def test_unacceptable_accept_gets_406_naming_the_formats(client):
    r = _predict(client, json={"displacement_mm": 5.0, "angle_deg": 2.0}, headers={"accept": "text/html"})
    assert r.status_code == 406
    [err] = r.json()["detail"]
    assert err["field"] == "accept" and "text/html" in err["message"] and "application/octet-stream" in err["message"]


@pytest.mark.parametrize(("content_type", "named"), [
    (None, "no Content-Type"),
    ("text/plain", "text/plain"),
    ("application/x-www-form-urlencoded", "application/x-www-form-urlencoded"),
    ("application/foo+json", "application/foo+json"),
    ("application/json; charset=latin-1", "charset=latin-1"),
])
def test_a_body_that_is_not_application_json_gets_415_naming_it(client, content_type, named):
    headers = {"content-type": content_type} if content_type else {}
    r = _predict(client, content=b'{"displacement_mm": 5, "angle_deg": 2}', headers=headers)
    assert r.status_code == 415
    [err] = r.json()["detail"]
    assert err["field"] == "content-type" and named in err["message"] and "application/json" in err["message"]


@pytest.mark.parametrize("content_type", ["application/json", "application/json; charset=utf-8",
                                          "Application/JSON;charset=\"UTF-8\""])
def test_application_json_with_or_without_utf8_charset_is_accepted(client, content_type):
    r = _predict(client, content=b'{"displacement_mm": 5, "angle_deg": 2, "region": "markers"}',
                 headers={"content-type": content_type})
    assert r.status_code == 200 and r.json()["count"] == 8


def test_a_body_that_is_not_utf8_gets_400_naming_the_body(client):
    r = _predict(client, content=b'{"displacement_mm": 5, "angle_deg": \xff}',
                 headers={"content-type": "application/json"})
    assert r.status_code == 400 and r.json()["detail"] == [
        {"field": "body", "message": "body: not UTF-8 text, as JSON must be", "type": "not_utf8"}]


def test_a_chunked_body_over_the_limit_gets_413(client):
    """No Content-Length: the limit is enforced on the bytes as they arrive."""
    chunks = (b" " * 16384 for _ in range(5))  # 80 KiB, over the test limit of 64 KiB
    r = _predict(client, content=chunks, headers={"content-type": "application/json"})
    assert r.status_code == 413
    [err] = r.json()["detail"]
    assert err["field"] == "body" and "65536 bytes" in err["message"]


ALLOWED = "https://viewer.example.org"


@pytest.fixture(scope="module")
def cors_client(settings):
    from fastapi.testclient import TestClient

    from service.app import create_app

    with TestClient(create_app(settings.model_copy(update={"cors_origins": [ALLOWED]}))) as c:
        yield c


def _preflight(client, origin, method="POST", headers="content-type"):
    return client.options("/predict", headers={"origin": origin, "access-control-request-method": method,
                                               "access-control-request-headers": headers})


def test_cors_allows_only_the_listed_origins(cors_client):
    ok = _preflight(cors_client, ALLOWED, headers="authorization, content-type")
    assert ok.status_code == 200 and ok.headers["access-control-allow-origin"] == ALLOWED
    assert "POST" in ok.headers["access-control-allow-methods"]
    refused = _preflight(cors_client, "https://evil.example.org")
    assert refused.status_code == 400 and "access-control-allow-origin" not in refused.headers
    assert refused.json()["detail"][0]["type"] == "cors_refused" and "origin" in refused.json()["detail"][0]["message"]
    assert _preflight(cors_client, ALLOWED, method="DELETE").status_code == 400
    r = cors_client.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0, "region": "markers"},
                         headers={"origin": ALLOWED, "accept": "application/octet-stream"})
    assert (r.headers["access-control-allow-origin"] == ALLOWED
            and "X-Count" in r.headers["access-control-expose-headers"])
    other = cors_client.get("/model", headers={"origin": "https://evil.example.org"})
    assert other.status_code == 200 and "access-control-allow-origin" not in other.headers


def test_no_cors_by_default(client):
    r = client.get("/model", headers={"origin": ALLOWED})
    assert "access-control-allow-origin" not in r.headers
    assert _preflight(client, ALLOWED).status_code == 405  # no CORS layer answers the preflight
