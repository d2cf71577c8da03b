"""Admission: per-client rate limit (429 with Retry-After) and the cap on /predict requests in the service (503)."""

import asyncio
import re
import threading

import httpx
import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.middleware.limits import RateLimit

BODY = {"displacement_mm": 5.0, "angle_deg": 2.0, "region": "markers"}


def test_the_bucket_refills_at_the_rate():
    limit = RateLimit(None, rate=2.0, burst=3)
    assert [limit._take("a", 0.0) for _ in range(3)] == [0.0, 0.0, 0.0]  # the burst
    assert limit._take("a", 0.0) == pytest.approx(0.5)  # one request per 1/rate seconds
    assert limit._take("a", 0.25) == pytest.approx(0.25)
    assert limit._take("a", 0.5) == 0.0 and limit._take("a", 0.5) > 0
    assert limit._take("b", 0.5) == 0.0  # another client has its own bucket
    assert limit._take("a", 100.0) == 0.0 and limit.buckets["a"][0] == pytest.approx(2.0)  # refills to burst, no more


def test_over_the_rate_gets_429_with_retry_after_per_client(settings):
    with TestClient(create_app(settings.model_copy(update={
            "rate_limit": 0.01, "rate_burst": 2, "auth_tokens": ["alice", "bob"]}))) as c:
        alice, bob = ({"authorization": f"Bearer {name}"} for name in ("alice", "bob"))
        assert [c.post("/predict", json=BODY, headers=alice).status_code for _ in range(2)] == [200, 200]
        r = c.post("/predict", json=BODY, headers=alice)
        assert r.status_code == 429 and 1 <= int(r.headers["retry-after"]) <= 100
        detail = r.json()["detail"][0]
        assert detail["type"] == "rate_limited" and "0.01 requests a second" in detail["message"]
        assert c.get("/model", headers=alice).status_code == 429  # every path but health counts
        assert c.get("/healthz").status_code == 200 and c.get("/readyz").status_code == 200
        assert c.post("/predict", json=BODY, headers=bob).status_code == 200  # bob has his own bucket
        text = c.get("/metrics", headers=bob).text
        assert re.search(r'predict_requests_total{[^}]*status="429"[^}]*} 1\.0', text)
        assert re.search(r'http_errors_total{path="/model",status="429"} 1\.0', text)


def test_a_full_service_answers_503_with_retry_after(settings, monkeypatch):
    from service.predict import pipeline

    entered, release = threading.Event(), threading.Event()
    real = pipeline.predict_batch

    def held(*args):
        entered.set()
        release.wait(5)
        return real(*args)

    monkeypatch.setattr(pipeline, "predict_batch", held)
    # the first waits in the batcher
    app = create_app(settings.model_copy(update={"max_pending": 1, "inline_max_ms": 0}))

    async def scenario():
        async with app.router.lifespan_context(app), httpx.AsyncClient(
                transport=httpx.ASGITransport(app=app), base_url="http://service") as client:
            first = asyncio.create_task(client.post("/predict", json=BODY))
            await asyncio.to_thread(entered.wait, 5)
            second = await client.post("/predict", json=BODY)
            health = await client.get("/healthz")
            release.set()
            return (await first).status_code, second, health.status_code, (await client.get("/metrics")).text

    first, second, health, metrics = asyncio.run(scenario())
    assert (first, second.status_code, health) == (200, 503, 200)
    assert second.headers["retry-after"] == "1" and second.json()["detail"][0]["type"] == "overloaded"
    assert re.search(r'predict_requests_total{[^}]*status="503"[^}]*} 1\.0', metrics)
