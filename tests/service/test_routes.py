"""POST /predict and the other endpoints: every field, every error path, on the committed default model."""

import numpy as np
import pytest

from service.model import read_model_folder

@pytest.fixture(scope="module")
def folder(settings):
    return read_model_folder(settings.model)


def _predict(client, **body):
    return client.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0, **body})


def test_full_mesh_json_has_every_field(client, folder):
    r = _predict(client)
    assert r.status_code == 200
    body = r.json()
    assert body["model"] == "default" and body["displacement_mm"] == 5.0 and body["angle_deg"] == 2.0
    assert body["region"] is None and body["count"] == len(folder.nodes) == len(body["positions"])
    assert "displacements" not in body and "node_ids" not in body
    moved = np.asarray(body["positions"]) - folder.nodes
    assert 4.5 < np.linalg.norm(moved, axis=1).max() < 5.5  # the guide patch moves by about 5 mm


def test_binary_reply_is_the_same_positions_as_float32(client):
    j = np.asarray(_predict(client).json()["positions"], dtype=np.float32)
    r = client.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0},
                    headers={"accept": "application/octet-stream"})
    assert r.status_code == 200 and r.headers["content-type"] == "application/octet-stream"
    assert int(r.headers["x-count"]) == len(j) and "count x 3" in r.headers["x-layout"]
    np.testing.assert_array_equal(np.frombuffer(r.content, dtype="<f4").reshape(-1, 3), j)


def test_region_decodes_its_nodes_and_matches_the_full_mesh(client, folder):
    full = np.asarray(_predict(client).json()["positions"])
    r = _predict(client, region="markers").json()
    ids = np.asarray(r["node_ids"])
    assert r["region"] == "markers" and r["count"] == 8 and len(r["displacements"]) == 8
    np.testing.assert_array_equal(ids, folder.regions["markers"])
    np.testing.assert_allclose(r["positions"], full[ids], atol=1e-5)
    np.testing.assert_allclose(np.asarray(r["positions"]) - folder.nodes[ids], r["displacements"], atol=1e-5)
    p = _predict(client, region="prostate").json()
    assert p["count"] == folder.manifest.regions["prostate"] and "displacements" not in p


def test_points_at_nodes_reproduce_the_nodal_answer(client, folder):
    """A point placed on a mesh node is interpolated to that node's decoded displacement."""
    full = np.asarray(_predict(client).json()["positions"])
    ids = folder.regions["prostate_surface"][:5]
    r = _predict(client, points=folder.nodes[ids].tolist()).json()
    assert r["count"] == 5 and r["region"] is None
    np.testing.assert_allclose(r["positions"], full[ids], atol=1e-4)


def test_zero_displacement_leaves_the_mesh_in_place(client, folder):
    r = client.post("/predict", json={"displacement_mm": 0.0, "angle_deg": -10.0}).json()
    assert np.abs(np.asarray(r["positions"]) - folder.nodes).max() < 0.01


@pytest.mark.parametrize(
    ("body", "field", "words"),
    [
        ({"displacement_mm": 10.5, "angle_deg": 0}, "displacement_mm", "from 0.0 to 10.0 mm"),
        ({"displacement_mm": -1, "angle_deg": 0}, "displacement_mm", "from 0.0 to 10.0 mm"),
        ({"displacement_mm": 5, "angle_deg": 11}, "angle_deg", "from -10.0 to 10.0 degrees"),
        ({"displacement_mm": "five", "angle_deg": 0}, "displacement_mm", "valid number"),
        ({"angle_deg": 0}, "displacement_mm", "Field required"),
        ({"displacement_mm": 5}, "angle_deg", "Field required"),
        ({"displacement_mm": 5, "angle_deg": 0, "region": "liver"}, "region", "one of adipose"),
        ({"displacement_mm": 5, "angle_deg": 0, "points": [[0, 0]]}, "points.0.2", "Field required"),
        ({"displacement_mm": 5, "angle_deg": 0, "points": [[0, 0, 35, 1]]}, "points.0", "at most 3"),
        ({"displacement_mm": 5, "angle_deg": 0, "points": []}, "points", "at least 1"),
        ({"displacement_mm": 5, "angle_deg": 0, "points": [[0, 0, 35]] * 51}, "points", "at most 50"),
        ({"displacement_mm": 5, "angle_deg": 0, "points": [[0, 0, 35]], "region": "markers"}, "body", "not both"),
        ({"displacement_mm": 5, "angle_deg": 0, "speed": 3}, "speed", "Extra inputs"),
        ({"displacement_mm": 5, "angle_deg": 0, "points": [[0, 0, 350]]}, "points.0.2", "less than or equal to 80"),
        ({"displacement_mm": 5, "angle_deg": 0, "points": [[0, 0, 35], [0, -21, 40]]}, "points.1", "outside the mesh"),
    ],
)
def test_bad_input_gets_422_naming_the_field(client, body, field, words):
    r = client.post("/predict", json=body)
    assert r.status_code == 422
    detail = r.json()["detail"]
    assert any(d["field"] == field and words in d["message"] for d in detail), detail


@pytest.mark.parametrize("raw", [b'{"displacement_mm": NaN, "angle_deg": 0}',
                                 b'{"displacement_mm": 5, "angle_deg": Infinity}',
                                 b'{"displacement_mm": 5, "angle_deg": 0, "points": [[0, 0, NaN]]}'])
def test_nan_and_inf_are_refused(client, raw):
    r = client.post("/predict", content=raw, headers={"content-type": "application/json"})
    assert r.status_code == 422 and "finite number" in r.text


def test_malformed_json_and_oversize_bodies(client):
    r = client.post("/predict", content=b'{"displacement_mm": 5,', headers={"content-type": "application/json"})
    assert r.status_code == 422 and r.json()["detail"][0]["field"] == "body" and "malformed JSON" in r.text
    r = client.post("/predict", content=b" " * (65 * 1024), headers={"content-type": "application/json"})
    assert r.status_code == 413 and "65536 bytes" in r.text


def test_model_summary(client, folder):
    m = client.get("/model").json()
    assert m["name"] == "default" and m["envelope"] == folder.manifest.envelope.model_dump(mode="json")
    assert m["regions"]["markers"] == 8 and m["metrics"]["table3"]["e_nn_mm"] <= 0.01
    assert m["limits"] == {"max_points": 50, "max_body_bytes": 65536}
    assert m["accuracy"] == folder.manifest.accuracy.model_dump(mode="json")  # the end-to-end bounds, per region
    assert m["fit"]["rank"] == folder.manifest.fit.rank and m["pca"]["rank"] == folder.manifest.pca.rank


def test_mesh_endpoint_gives_nodes_and_surfaces(client, folder):
    m = client.get("/mesh").json()
    assert len(m["nodes"]) == len(folder.nodes) and set(m["surfaces"]) == set(folder.surfaces)
    tri = np.asarray(m["surfaces"]["prostate"])
    assert tri.shape[1] == 3 and tri.max() < len(folder.nodes)


def test_health_ready_and_metrics(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    assert client.get("/readyz").json()["status"] == "ready"
    _predict(client, region="markers")
    text = client.get("/metrics").text
    assert 'predict_requests_total{format="json",region="markers",status="200"}' in text
    assert 'predict_latency_seconds_bucket{le="0.001",region="markers"}' in text


def test_docs_and_schema_state_the_ranges(client):
    schema = client.get("/openapi.json").json()
    req = schema["components"]["schemas"]["PredictRequest"]["properties"]
    assert req["displacement_mm"]["minimum"] == 0.0 and req["displacement_mm"]["maximum"] == 10.0
    assert req["angle_deg"]["minimum"] == -10.0 and client.get("/docs").status_code == 200


@pytest.mark.parametrize("batching", [False, True])
def test_healthz_is_answered_while_a_predict_is_in_flight(settings, monkeypatch, batching):
    """A decode not cheap enough to run inline runs off the event loop: with one predict held inside the
    decode, /healthz still answers (inline_max_ms 0 makes every decode such a one)."""
    import asyncio
    import threading

    import httpx

    from service.predict import pipeline
    from service.app import create_app

    entered, release = threading.Event(), threading.Event()
    real = pipeline.predict_batch  # every path decodes through it: the batcher's lanes, or one thread hop

    def held(*args):
        entered.set()
        release.wait(3)
        return real(*args)

    monkeypatch.setattr(pipeline, "predict_batch", held)
    app = create_app(settings.model_copy(update={"batching": batching, "inline_max_ms": 0}))

    async def scenario():
        async with app.router.lifespan_context(app), httpx.AsyncClient(
                transport=httpx.ASGITransport(app=app), base_url="http://service") as client:
            predicting = asyncio.create_task(client.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0}))
            await asyncio.to_thread(entered.wait, 3)
            health = await client.get("/healthz")
            in_flight = not predicting.done()
            release.set()
            return health.status_code, in_flight, (await predicting).status_code

    assert asyncio.run(scenario()) == (200, True, 200)


def test_every_mesh_node_sent_back_as_a_point_is_accepted(client, folder):
    """GET /mesh's float32 nodes, posted back as points, are inside and give their own nodal displacement."""
    nodes = np.asarray(client.get("/mesh").json()["nodes"])  # float32 values
    r = client.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0},
                    headers={"accept": "application/octet-stream"})
    nodal = np.frombuffer(r.content, dtype="<f4").reshape(-1, 3) - nodes.astype(np.float32)
    max_points = client.get("/model").json()["limits"]["max_points"]
    refused, got = [], []
    for start in range(0, len(nodes), max_points):
        r = _predict(client, points=nodes[start:start + max_points].tolist())
        if r.status_code != 200:
            refused.append(r.json()["detail"][0]["message"])
            continue
        got.append(np.asarray(r.json()["displacements"]))
    assert not refused, f"{len(refused)} chunks refused, first: {refused[0]}"
    np.testing.assert_allclose(np.concatenate(got), nodal, atol=1e-4)


def _route_class(app, path: str) -> type:
    """The class of the app's route for `path` (FastAPI keeps included routers' routes in their own router)."""
    routes = list(app.routes)
    while routes:
        route = routes.pop()
        if getattr(route, "path", None) == path:
            return type(route)
        routes += getattr(getattr(route, "original_router", None), "routes", [])
    raise LookupError(path)


@pytest.mark.parametrize("body, accept", [
    ({}, "application/json"), ({}, "application/octet-stream"), ({"region": "markers"}, "application/json"),
    ({"region": "prostate"}, "application/octet-stream"), ({"points": "prostate_surface"}, "application/json"),
    ({"materials": {"prostate": {"youngs_kpa": 70.0, "std_percent": 10.0}}}, "application/json"),
    ({"materials": {"adipose": {"shear_wave_speed_m_s": 2.0}}, "region": "markers"}, "application/octet-stream")])
def test_a_valid_body_skips_fastapi_dependencies_and_gets_the_same_reply(client, folder, monkeypatch, body, accept):
    """/predict's direct path (service/predict/routes.py, PredictRoute) gives the same status, headers and bytes as
    FastAPI's path, and solves no dependency on the way; an invalid body takes FastAPI's path, for its 422."""
    import fastapi.routing

    solved, solve = [], fastapi.routing.solve_dependencies

    async def counting(*args, **kwargs):
        solved.append(1)
        return await solve(*args, **kwargs)

    monkeypatch.setattr(fastapi.routing, "solve_dependencies", counting)
    if body.get("points"):
        body = {"points": folder.nodes[folder.regions[body["points"]][:7]].tolist()}
    request = {"json": {"displacement_mm": 4.0, "angle_deg": -3.0, **body}, "headers": {"accept": accept}}
    direct = client.post("/predict", **request)
    assert direct.status_code == 200 and not solved
    monkeypatch.setattr(_route_class(client.app, "/predict"), "direct", False)
    general = client.post("/predict", **request)
    assert solved and general.status_code == 200
    assert dict(direct.headers) == dict(general.headers) and direct.content == general.content
    monkeypatch.undo()
    solved.clear()
    monkeypatch.setattr(fastapi.routing, "solve_dependencies", counting)
    bad = client.post("/predict", json={**request["json"], "angle_deg": 99.0}, headers=request["headers"])
    assert bad.status_code == 422 and bad.json()["detail"][0]["field"] == "angle_deg" and solved
