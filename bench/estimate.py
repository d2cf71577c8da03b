"""Time POST /estimate and POST /plan in process and served, and the estimate stream at 30 frames/s.

    python -m bench estimate [--model models/default] [--requests 200] [--stream-s 5] [--publish]

/estimate: the model's 8 markers at random states of its envelope (nominal stiffness) with 0.2 mm Gaussian noise
and one target; timed through the route's own function (validation to reply) in process, then as POST against
`python -m service --workers 1` on loopback, one client. /plan: random prostate points, the push left to the plan.
The stream: one WebSocket client sends a frame every 1/30 s (the markers of a guide moving slowly through the
envelope, with noise) and times each reply; the lag is the time from a frame's send to its reply.
"""

from __future__ import annotations

import argparse
import http.client
import json
import time
from pathlib import Path

import numpy as np

from service.estimate.fit import StateSpace, point_set, positions
from service.estimate.routes import Closing, run_estimate, run_plan
from service.estimate.schemas import estimate_request_model, plan_request_model
from service.info import model_info
from service.model import Predictor, read_model_folder
from service.settings import DEFAULT_MODEL, Settings

from studies import results
from tools import loadtest

FPS = 30.0


def bodies(folder, predictor, n: int, seed: int) -> tuple[list[dict], list[dict]]:
    """n /estimate bodies (noisy markers at random states) and n /plan bodies (prostate points)."""
    rng = np.random.default_rng(seed)
    space, markers = StateSpace.of(predictor), folder.regions["markers"]
    pts = point_set(predictor, node_ids=markers, points=np.zeros((0, 3)))
    env = folder.manifest.envelope
    states = np.column_stack([rng.uniform(*env.displacement_mm, n), rng.uniform(*env.angle_deg, n),
                              np.zeros((n, space.n_materials))])
    at = positions(predictor, space, pts, states) + rng.normal(0, 0.2, (n, len(markers), 3))
    prostate = np.flatnonzero(folder.mesh.tissue == folder.manifest.mesh.tissues.index("prostate"))
    lesions = folder.nodes[folder.tets[rng.choice(prostate, n)][:, :4]].mean(axis=1)
    estimate = [{"markers": [{"index": i, "position_mm": p.tolist(), "std_mm": 0.2} for i, p in enumerate(a)],
                 "targets": [lesion.tolist()]} for a, lesion in zip(at, lesions)]
    return estimate, [{"lesion_mm": lesion.tolist()} for lesion in lesions]


def _ms(times: list[float]) -> dict:
    t = np.array(times)
    return {"p50_ms": float(np.percentile(t, 50)), "p99_ms": float(np.percentile(t, 99)), "max_ms": float(t.max()),
            "n": len(t)}


def in_process(model: Path, estimate_bodies: list[dict], plan_bodies: list[dict]) -> dict:
    folder = read_model_folder(model)
    closing, info = Closing.of(Predictor(folder)), model_info(folder, Settings(model=model))
    est_model = estimate_request_model(info, 10_000, len(closing.markers))
    plan_model = plan_request_model(info)
    out = {}
    for name, run, model_, items in (("estimate", lambda b: run_estimate(closing, b), est_model, estimate_bodies),
                                     ("plan", lambda b: run_plan(closing, b), plan_model, plan_bodies)):
        run(model_.model_validate(items[0]))  # first call of each shape allocates
        times = []
        for body in items:
            t0 = time.perf_counter()
            run(model_.model_validate(body))
            times.append((time.perf_counter() - t0) * 1e3)
        out[name] = _ms(times)
    return out


def served(url: str, estimate_bodies: list[dict], plan_bodies: list[dict]) -> dict:
    host, port = loadtest.loopback(url)
    conn, out = http.client.HTTPConnection(host, port, timeout=30), {}
    for name, items in (("estimate", estimate_bodies), ("plan", plan_bodies)):
        times = []
        for i, body in enumerate(items):
            data = json.dumps(body).encode()
            t0 = time.perf_counter()
            conn.request("POST", f"/{name}", body=data, headers={"content-type": "application/json"})
            reply = conn.getresponse()
            reply.read()
            if reply.status != 200:
                raise SystemExit(f"error: POST /{name} answered {reply.status}")
            if i:  # the first opens the connection
                times.append((time.perf_counter() - t0) * 1e3)
        out[name] = _ms(times)
    return out


def stream(url: str, folder, predictor, seconds: float, seed: int) -> dict:
    """Frames at 30/s for `seconds`: each reply's lag from its frame's send, and the rate kept."""
    from websockets.sync.client import connect

    rng = np.random.default_rng(seed + 1)
    space, markers = StateSpace.of(predictor), folder.regions["markers"]
    pts = point_set(predictor, node_ids=markers, points=np.zeros((0, 3)))
    n = int(seconds * FPS)
    env = folder.manifest.envelope
    path = np.column_stack([np.linspace(env.displacement_mm[0] + 1, env.displacement_mm[1], n),
                            np.linspace(env.angle_deg[0], env.angle_deg[1], n), np.zeros((n, space.n_materials))])
    at = positions(predictor, space, pts, path) + rng.normal(0, 0.2, (n, len(markers), 3))
    frames = [json.dumps({"markers": [{"index": i, "position_mm": p.tolist(), "std_mm": 0.2} for i, p in enumerate(a)]})
              for a in at]
    lags = []
    with connect(url.replace("http://", "ws://") + "/estimate/stream") as ws:
        start = time.perf_counter()
        for k, frame in enumerate(frames):
            due = start + k / FPS
            time.sleep(max(0.0, due - time.perf_counter()))
            t0 = time.perf_counter()
            ws.send(frame)
            json.loads(ws.recv())
            lags.append((time.perf_counter() - t0) * 1e3)
        elapsed = time.perf_counter() - start
    return {"frames": n, "fps_sent": FPS, "fps_kept": n / elapsed, **{f"lag_{k}": v for k, v in _ms(lags).items()}}


def report(data: dict) -> str:
    lines = [f"# POST /estimate, POST /plan and the stream, {data['model']}", "",
             "| request | p50 | p99 | max | requests |", "|---|---|---|---|---|"]
    for where in ("in_process", "served"):
        for route, v in data[where].items():
            lines.append(f"| /{route}, {where.replace('_', ' ')} | {v['p50_ms']:.2f} ms | {v['p99_ms']:.2f} ms | "
                         f"{v['max_ms']:.2f} ms | {v['n']} |")
    st = data["stream"]
    lines += ["", f"The stream: {st['frames']} frames sent at {st['fps_sent']:g}/s, {st['fps_kept']:.1f}/s kept; each "
              f"frame's lag from its send to its reply p50 {st['lag_p50_ms']:.2f} ms, p99 {st['lag_p99_ms']:.2f} ms, "
              f"max {st['lag_max_ms']:.2f} ms."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench estimate", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    ap.add_argument("--requests", type=int, default=200, help="requests per route (default 200)")
    ap.add_argument("--stream-s", type=float, default=5.0, help="seconds of streaming at 30 frames/s (default 5)")
    ap.add_argument("--seed", type=int, default=0)
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    folder = read_model_folder(args.model)
    predictor = Predictor(folder)
    est, plan = bodies(folder, predictor, args.requests, args.seed)
    data = {"model": folder.manifest.name, "in_process": in_process(args.model, est, plan)}
    with loadtest.local_service("--model", str(args.model), "--workers", "1") as url:
        data["served"] = served(url, est, plan)
        data["stream"] = stream(url, folder, predictor, args.stream_s, args.seed)
    data["report_md"] = report(data)
    print(data["report_md"])
    print(f"wrote {results.write('bench_estimate', data, publish=args.publish)}")
    return 0
