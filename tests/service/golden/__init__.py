"""Golden replies: a recorded set of requests and the exact bytes the service answered, on models/default.

    python -m tests.service.golden --write    # record replies.json anew (after a change meant to alter replies)
    python -m tests.service.golden            # compare, as tests/service/test_golden_replies.py does

A refactor of the service must leave every reply the same bytes: status, headers and body. The fixture
(replies.json) holds each request, and of its reply the status, the headers, the body's sha256 and length,
and the body itself where it is small. /metrics is left out (it holds timings); no other reply holds a timing or
an id.

Bytes depend on the machine and the libraries as well as on the code: a decoded float's last bit on the CPU's
instruction set and on onnxruntime, numpy and scipy (the BLAS under /estimate); error messages and the OpenAPI
document on FastAPI, Starlette and pydantic. So the fixture records `environment()`, and a case is compared
where the parts of it that the reply depends on are the same; elsewhere it is skipped, naming what differs.
Every case is replayed on each of VARIANTS (batched, decoded on the event loop, unbatched): replies must be the
same bytes whichever path decoded them, everywhere.
"""

from __future__ import annotations

import base64
import hashlib
import json
import platform
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path
from typing import Iterator

ROOT = Path(__file__).resolve().parents[3]
MODEL = ROOT / "models" / "default"
FIXTURE = Path(__file__).with_name("replies.json")
COMMAND = "python -m tests.service.golden --write"
STORED_BODY_BYTES = 4096  # a body up to this size is kept whole in the fixture (readable diffs), larger ones by hash
# as tests/service/conftest.py's `settings`: 50 points and a 64 KiB body make the 422 and 413 cheap to provoke
BASE_SETTINGS = {"max_points": 50, "max_body_bytes": 64 * 1024, "threads": 1}
# Every path /predict may take: the batcher (no request decoded on the loop), the event loop (every full-mesh and
# region decode counts as cheap), and the thread pool (batching off).
VARIANTS = {
    "batched": {"inline_max_ms": 0.0},
    "inline": {"inline_max_ms": 10.0},
    "unbatched": {"batching": False},
}
RECORDED_WITH = "batched"
FRAMEWORK = ("fastapi", "starlette", "pydantic", "pydantic-core", "orjson")
NUMERICS = ("onnxruntime", "numpy", "scipy", "meshio", "trimesh")
# replies computed from decoded floats: exact only where the CPU and NUMERICS match the recording
NUMERIC_PATHS = ("/predict", "/estimate", "/plan", "/estimate/stream")

GUIDE = {"displacement_mm": 5.0, "angle_deg": 2.0}
JSON_HEADERS = {"content-type": "application/json"}
BINARY_ACCEPT = {"accept": "application/octet-stream"}
INSIDE = [[0.0, 0.0, 35.0], [1.5, -2.0, 33.0], [-3.0, 1.0, 37.5]]  # reference points in the prostate, mm
LUMEN = [0.0, -21.0, 40.0]  # inside the bounding box, in the rectal lumen: in no tet
MATERIALS = {"prostate": {"youngs_kpa": 70.0}, "rectal_wall": {"shear_wave_speed_m_s": 7.5, "std_percent": 10.0},
             "adipose": {"youngs_kpa": 11.0, "std": 0.5}}


def environment() -> dict:
    """What a reply's bytes depend on besides the code: the CPU and the libraries' versions."""
    flags, model_name = set(), platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "flags":
                flags = set(value.split())
            elif key.strip() == "model name":
                model_name = value.strip()
    except OSError:
        pass
    isa = sorted(flags & {"avx", "avx2", "fma", "avx512f", "avx512bw", "avx512vl", "avx512_vnni", "amx_tile"})
    return {"cpu": {"machine": platform.machine(), "model": model_name, "isa": isa},
            "framework": {name: metadata.version(name) for name in FRAMEWORK},
            "numerics": {name: metadata.version(name) for name in NUMERICS},
            "python": platform.python_version()}


def differences(recorded: dict, now: dict, *, numeric: bool) -> list[str]:
    """What differs between two environments that a reply of this kind depends on (empty: compare its bytes)."""
    parts = ["framework"] + (["cpu", "numerics"] if numeric else [])
    return [f"{part}: recorded {recorded.get(part)}, here {now.get(part)}" for part in parts
            if recorded.get(part) != now.get(part)]


def is_numeric(case: dict) -> bool:
    """A reply computed from decoded floats: a 200 of /predict, /estimate or /plan, or the stream's frames."""
    return case["request"]["path"].split("?")[0] in NUMERIC_PATHS and case["reply"]["status"] in (200, 101)


@contextmanager
def served(variant: str) -> Iterator:
    """A TestClient of the app on models/default with the golden settings and one of VARIANTS."""
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    with TestClient(create_app(Settings(model=MODEL, **BASE_SETTINGS, **VARIANTS[variant]))) as client:
        yield client


def _predict(name: str, body: dict, headers: dict | None = None, *, query: str = "") -> dict:
    return {"name": name, "method": "POST", "path": "/predict" + query, "headers": headers or {}, "json": body}


def _post(name: str, path: str, body: dict) -> dict:
    return {"name": name, "method": "POST", "path": path, "headers": {}, "json": body}


def _get(name: str, path: str, headers: dict | None = None) -> dict:
    return {"name": name, "method": "GET", "path": path, "headers": headers or {}}


def _raw(name: str, text: str | None = None, headers: dict | None = None, *, b64: str | None = None,
         pad_to: int = 0) -> dict:
    """POST /predict with a body given as text (padded with spaces to `pad_to` bytes) or as base64 bytes."""
    body = {"b64": b64} if b64 is not None else {"text": text, "pad_to": pad_to}
    return {"name": name, "method": "POST", "path": "/predict", "headers": {**JSON_HEADERS, **(headers or {})},
            **body}


def predict_requests() -> list[dict]:
    """POST /predict: every target (all nodes, regions, points), JSON and binary, with materials and their std."""
    return [
        _predict("predict_all_json", GUIDE),
        _predict("predict_all_binary", GUIDE, BINARY_ACCEPT),
        _predict("predict_all_at_rest_json", {"displacement_mm": 0.0, "angle_deg": -10.0}),
        _predict("predict_all_binary_by_q", {"displacement_mm": 9.5, "angle_deg": 10.0},
                 {"accept": "application/json;q=0.5, application/octet-stream;q=0.9"}),
        _predict("predict_all_json_by_q", GUIDE, {"accept": "application/json, application/octet-stream"}),
        _predict("predict_markers_json", {**GUIDE, "region": "markers"}),
        _predict("predict_markers_binary", {**GUIDE, "region": "markers"}, BINARY_ACCEPT),
        _predict("predict_prostate_json", {"displacement_mm": 3.25, "angle_deg": -4.5, "region": "prostate"}),
        _predict("predict_adipose_json", {**GUIDE, "region": "adipose"}),  # over SMALL_JSON_ROWS: written off the loop
        _predict("predict_guide_patch_binary", {**GUIDE, "region": "guide_patch"}, BINARY_ACCEPT),
        _predict("predict_points_json", {**GUIDE, "points": INSIDE}),
        _predict("predict_points_binary", {**GUIDE, "points": INSIDE}, BINARY_ACCEPT),
        _predict("predict_one_point_json", {"displacement_mm": 7.0, "angle_deg": 1.0, "points": INSIDE[:1]}),
        _predict("predict_all_materials_json", {**GUIDE, "materials": MATERIALS}),
        _predict("predict_all_materials_binary", {**GUIDE, "materials": MATERIALS}, BINARY_ACCEPT),
        _predict("predict_markers_materials_json", {**GUIDE, "region": "markers", "materials": MATERIALS}),
        _predict("predict_points_materials_json", {**GUIDE, "points": INSIDE, "materials": MATERIALS}),
        _predict("predict_points_uncertain_json", {**GUIDE, "points": INSIDE, "materials": {
            "prostate": {"youngs_kpa": 60.0, "std_percent": 40.0},
            "bladder": {"shear_wave_speed_m_s": 5.8, "std": 1.0}}}),
        _predict("predict_markers_no_std_json", {**GUIDE, "region": "markers", "materials": {
            name: {"std_percent": 0.0} for name in ("prostate", "rectal_wall", "adipose", "bladder")}}),
        # a query string takes FastAPI's own path rather than the direct one (routes.PredictRoute)
        _predict("predict_markers_with_query_json", {**GUIDE, "region": "markers"}, query="?unused=1"),
        _predict("predict_points_with_query_binary", {**GUIDE, "points": INSIDE}, BINARY_ACCEPT, query="?unused=1"),
        _predict("predict_export_ply", GUIDE, query="?format=ply"),
        _predict("predict_export_vtu", {"displacement_mm": 2.0, "angle_deg": 0.0}, query="?format=vtu"),
        _predict("predict_export_glb", GUIDE, query="?format=glb"),
    ]


def error_requests() -> list[dict]:
    """Every error reply of /predict and the other routes: 400, 404, 405, 406, 413, 415, 422."""
    return [
        _predict("error_displacement_over_envelope", {"displacement_mm": 10.5, "angle_deg": 0}),
        _predict("error_angle_under_envelope", {"displacement_mm": 5, "angle_deg": -11}),
        _predict("error_displacement_not_a_number", {"displacement_mm": "five", "angle_deg": 0}),
        _predict("error_missing_fields", {}),
        _predict("error_unknown_region", {**GUIDE, "region": "liver"}),
        _predict("error_region_and_points", {**GUIDE, "region": "markers", "points": INSIDE}),
        _predict("error_extra_field", {**GUIDE, "speed": 3}),
        _predict("error_point_short", {**GUIDE, "points": [[0, 0]]}),
        _predict("error_no_points", {**GUIDE, "points": []}),
        _predict("error_too_many_points", {**GUIDE, "points": [[0, 0, 35]] * 51}),
        _predict("error_point_off_bounds", {**GUIDE, "points": [[0, 0, 350]]}),
        _predict("error_point_outside_mesh", {**GUIDE, "points": [INSIDE[0], LUMEN]}),
        _predict("error_point_outside_mesh_with_query", {**GUIDE, "points": [LUMEN]}, query="?unused=1"),
        _predict("error_materials_out_of_range", {**GUIDE, "materials": {"prostate": {"youngs_kpa": 500.0}}}),
        _predict("error_materials_both_values", {**GUIDE, "materials": {
            "prostate": {"youngs_kpa": 60.0, "shear_wave_speed_m_s": 4.0}}}),
        _predict("error_materials_std_over_value",
                 {**GUIDE, "materials": {"prostate": {"youngs_kpa": 60.0, "std": 61.0}}}),
        _predict("error_materials_unknown_tissue", {**GUIDE, "materials": {"liver": {"youngs_kpa": 60.0}}}),
        _predict("error_format_with_materials", {**GUIDE, "materials": MATERIALS}, query="?format=vtu"),
        _predict("error_format_unknown", GUIDE, query="?format=stl"),
        _predict("error_format_with_region", {**GUIDE, "region": "prostate"}, query="?format=ply"),
        _predict("error_not_acceptable", GUIDE, {"accept": "text/html"}),
        _raw("error_malformed_json", '{"displacement_mm": 5, "angle_deg":'),
        _raw("error_nan_literal", '{"displacement_mm": NaN, "angle_deg": 0}'),
        _raw("error_not_utf8", b64=base64.b64encode(b'{"displacement_mm": 5, "angle_deg": "\xff"}').decode()),
        _raw("error_text_plain", '{"displacement_mm": 5, "angle_deg": 0}', {"content-type": "text/plain"}),
        _raw("error_no_content_type", '{"displacement_mm": 5, "angle_deg": 0}', {"content-type": ""}),
        _raw("error_body_too_large", '{"displacement_mm": 5, "angle_deg": 0}', pad_to=70_000),
        _get("error_not_found", "/nope"),
        _get("error_predict_by_get", "/predict"),
        _post("error_estimate_nothing_tracked", "/estimate", {"targets": [INSIDE[0]]}),
        _post("error_estimate_bad_marker", "/estimate",
              {"markers": [{"index": 8, "position_mm": [0, 0, 0], "std_mm": 0.2}]}),
        _post("error_estimate_target_outside_mesh", "/estimate", {
            "points": [{"reference_mm": INSIDE[0], "position_mm": INSIDE[0], "std_mm": 0.2}], "targets": [LUMEN]}),
        _post("error_plan_outside_mesh", "/plan", {"lesion_mm": LUMEN}),
        _post("error_plan_over_envelope", "/plan", {"lesion_mm": INSIDE[0], "displacement_mm": 12.0}),
    ]


def other_requests(markers: list[list[float]]) -> list[dict]:
    """GET routes, the OpenAPI document, /estimate (from `markers`, observed positions of the 8 markers), /plan."""
    observed = [{"index": i, "position_mm": p, "std_mm": 0.2} for i, p in enumerate(markers)]
    return [
        _get("model", "/model"),
        _get("mesh", "/mesh"),
        _get("healthz", "/healthz"),
        _get("readyz", "/readyz"),
        _get("openapi", "/openapi.json"),
        _get("docs", "/docs"),
        _get("redoc", "/redoc"),
        _get("viewer", "/viewer"),
        _post("estimate_markers", "/estimate", {"markers": observed, "targets": [INSIDE[0], INSIDE[1]]}),
        _post("estimate_markers_with_prior", "/estimate", {
            "markers": observed[:6], "prior": {"displacement_mm": {"value": 5.0, "std": 0.5}},
            "materials": MATERIALS, "targets": [INSIDE[2]]}),
        _post("estimate_points_no_stiffness_prior", "/estimate", {
            "points": [{"reference_mm": p, "position_mm": [p[0], p[1] + 3.0, p[2]], "std_mm": 0.3} for p in INSIDE],
            "stiffness_prior": False}),
        _post("plan_reachable", "/plan", {"lesion_mm": INSIDE[0], "displacement_mm": 6.0}),
        _post("plan_best_push", "/plan", {"lesion_mm": INSIDE[1], "materials": MATERIALS}),
        _post("plan_unreachable", "/plan", {"lesion_mm": [30.0, 0.0, 35.0]}),
        {"name": "estimate_stream", "method": "WS", "path": "/estimate/stream", "headers": {},
         "frames": [json.dumps({"markers": observed}), json.dumps({"markers": observed[:4], "targets": [INSIDE[0]]}),
                    json.dumps({"markers": []}), "not json"]},
    ]


def observed_markers(client) -> list[list[float]]:
    """The markers' positions at GUIDE, rounded to 0.01 mm: a tracker's view of them."""
    reply = client.post("/predict", json={**GUIDE, "region": "markers"})
    return [[round(v, 2) for v in p] for p in reply.json()["positions"]]


def replay(client, request: dict) -> dict:
    """Send one recorded request; the reply as recorded: status, headers, body (sha256, length, small ones whole)."""
    if request["method"] == "WS":
        with client.websocket_connect(request["path"]) as ws:
            texts = []
            for frame in request["frames"]:
                ws.send_text(frame)
                texts.append(ws.receive_text())
        return _record(101, {}, "\n".join(texts).encode())
    kwargs = {"headers": request["headers"]}
    if "json" in request:
        kwargs["json"] = request["json"]
    elif "b64" in request:
        kwargs["content"] = base64.b64decode(request["b64"])
    elif "text" in request:
        kwargs["content"] = request["text"].encode().ljust(request.get("pad_to", 0))
    reply = client.request(request["method"], request["path"], **kwargs)
    return _record(reply.status_code, dict(reply.headers), reply.content)


# A served file's validators come from its mtime on this disk (Starlette's FileResponse), which a checkout sets:
# recorded as present, not by value, so a fresh clone compares the same.
FILE_VALIDATORS = ("etag", "last-modified")


def _record(status: int, headers: dict, body: bytes) -> dict:
    headers = {k: "(from the file's mtime)" if k in FILE_VALIDATORS else v for k, v in headers.items()}
    out = {"status": status, "headers": dict(sorted(headers.items())), "sha256": hashlib.sha256(body).hexdigest(),
           "bytes": len(body)}
    if len(body) <= STORED_BODY_BYTES:
        try:
            out["body"] = body.decode()
        except UnicodeDecodeError:
            out["body_b64"] = base64.b64encode(body).decode()
    return out


def record() -> dict:
    """Every request and its reply on the RECORDED_WITH variant, with the environment that produced them."""
    with served(RECORDED_WITH) as client:
        requests = predict_requests() + error_requests() + other_requests(observed_markers(client))
        cases = [{"request": r, "reply": replay(client, r)} for r in requests]
    return {"about": f"golden replies of the service on models/default (tests/service/golden); rewrite: {COMMAND}",
            "settings": BASE_SETTINGS, "recorded_with": RECORDED_WITH, "environment": environment(), "cases": cases}


def load() -> dict:
    return json.loads(FIXTURE.read_text())


def write(path: Path = FIXTURE) -> dict:
    golden = record()
    path.write_text(json.dumps(golden, indent=1, ensure_ascii=False) + "\n")
    return golden
