"""Time 10,000-point /predict requests, and /healthz while they run.

    python -m bench points [--model models/default] [--points 10000] [--repeat 5]

Three point sets: all in the rectal lumen (inside the bounding box, in no tet: a 422), uniform in
the bounding box (mostly inside; the first lumen point makes it a 422) and inside random tets (a
200 with every point decoded). Each is timed in process through predict() (locate, decode,
interpolate), then as POST /predict against `python -m service` on loopback, while a second
connection polls /healthz; the /healthz latencies measured while a POST was in flight are printed.
"""

from __future__ import annotations

import argparse
import http.client
import os
import threading
import time
from pathlib import Path

import numpy as np
import orjson

from service.info import model_info
from service.model import OutsideMesh, Predictor, read_model_folder
from service.predict.decode import predict
from service.predict.schemas import predict_request_model
from service.settings import DEFAULT_MODEL, Settings

from bench._report import Report
from studies import results
from tools import loadtest


def point_sets(folder, n: int, lumen_mm: list[float], seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    tets = rng.integers(len(folder.tets), size=n)
    inside = np.einsum("kv,kvd->kd", rng.dirichlet(np.ones(4), size=n), folder.nodes[folder.tets[tets, :4]])
    box = rng.uniform(folder.nodes.min(axis=0), folder.nodes.max(axis=0), size=(n, 3))
    return {"lumen": np.tile(lumen_mm, (n, 1)), "box": box, "inside": inside}


def in_process_ms(predictor, request, repeat: int) -> tuple[float, float, str]:
    """Median wall and CPU time of predict() in ms (they differ when other processes share the cores),
    and what it answered."""
    wall, cpu, outcome = [], [], ""
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            outcome = f"{len(predict(predictor, request).positions)} positions"
        except OutsideMesh as exc:
            outcome = f"outside the mesh at points.{exc.index}"
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return float(np.median(wall)), float(np.median(cpu)), outcome


def over_http(url: str, bodies: dict[str, bytes], repeat: int) -> tuple[dict[str, list], list[float]]:
    """POST each body `repeat` times; meanwhile GET /healthz in a loop. Returns POST (ms, status) per set
    and the /healthz latencies (ms) of the polls that started and ended while a POST was in flight."""
    host, port = loadtest.loopback(url)
    in_flight, done, during = threading.Event(), threading.Event(), []

    def poll_health():
        conn = http.client.HTTPConnection(host, port, timeout=10)
        while not done.is_set():
            busy = in_flight.is_set()
            t0 = time.perf_counter()
            conn.request("GET", "/healthz")
            conn.getresponse().read()
            if busy and in_flight.is_set():
                during.append((time.perf_counter() - t0) * 1e3)
            time.sleep(0.0005)

    poller = threading.Thread(target=poll_health, daemon=True)
    poller.start()
    conn, posts = http.client.HTTPConnection(host, port, timeout=60), {}
    for name, body in bodies.items():
        posts[name] = []
        for _ in range(repeat):
            in_flight.set()
            t0 = time.perf_counter()
            conn.request("POST", "/predict", body=body, headers={"content-type": "application/json"})
            reply = conn.getresponse()
            reply.read()
            in_flight.clear()
            posts[name].append(((time.perf_counter() - t0) * 1e3, reply.status))
            time.sleep(0.02)
    done.set()
    poller.join()
    return posts, during


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m bench points", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--lumen", type=float, nargs=3, default=[0.0, -21.0, 40.0], help="a point in the rectal lumen, mm")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    say = Report()

    folder = read_model_folder(args.model)
    settings = Settings(model=args.model, max_points=args.points)
    request_model = predict_request_model(model_info(folder, settings), args.points)
    predictor = Predictor(folder)
    sets = point_sets(folder, args.points, args.lumen)
    say(f"model {folder.manifest['name']}: {len(folder.nodes)} nodes, {len(folder.tets)} tets; "
          f"{args.points} points per request, median of {args.repeat}; load average {os.getloadavg()[0]:.1f}")
    for name, points in sets.items():
        body = request_model(displacement_mm=5.0, angle_deg=2.0, points=points.tolist())
        wall, cpu, outcome = in_process_ms(predictor, body, args.repeat)
        say(f"  predict() in process, {name:6s}: {wall:6.1f} ms wall, {cpu:6.1f} ms CPU  ({outcome})")

    bodies = {name: orjson.dumps({"displacement_mm": 5.0, "angle_deg": 2.0, "points": points},
                                 option=orjson.OPT_SERIALIZE_NUMPY) for name, points in sets.items()}
    with loadtest.local_service("--model", str(args.model), "--max-points", str(args.points),
                                "--max-body-bytes", str(4 * max(map(len, bodies.values())))) as url:
        posts, health = over_http(url, bodies, args.repeat)
    for name, runs in posts.items():
        ms = np.array([t for t, _ in runs])
        say(f"  POST /predict, {name:6s}: median {np.median(ms):7.1f} ms, max {ms.max():7.1f} ms "
              f"(status {sorted({s for _, s in runs})}, {len(bodies[name]) / 1e3:.0f} kB body)")
    if health:
        say(f"  GET /healthz during those POSTs: {len(health)} polls, median {np.median(health):.2f} ms, "
              f"p95 {np.percentile(health, 95):.2f} ms, max {max(health):.2f} ms")
    else:
        say("  GET /healthz during those POSTs: no poll completed inside a POST")
    print(f"wrote {results.write('bench_points', {'lines': say.lines}, publish=args.publish)}")
    return 0
