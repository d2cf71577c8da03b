"""Soak and fault test of a running service on loopback: mixed traffic at saturation for a bounded time.

    python -m service --access-log off &          # or make serve
    python -m bench soak --url http://127.0.0.1:8000 --duration 600

Closed-loop clients (default 8) send mixed requests with 5 % bad ones and 1 % with a point in the
rectal lumen; 20 slow clients trickle requests, read slowly, give up halfway or idle. After a
warm-up, it prints latency p50/p99, throughput, replies by status, /healthz latency (overall and
the worst minute), and the service's RSS and open file descriptors at start and end, then the
targets: no 5xx, RSS within 10 % of its start, descriptors back to baseline, /healthz p99 <= 20 ms
in every minute. The start figures are read after the warm-up, once its clients have gone: the
first requests open files that stay open and grow buffers that stay. Exit status 1 if a target is
missed. Stops by itself (at most 3600 s plus the warm-up).

The mix: full mesh as JSON and binary, regions and interior points; the bad requests are each kind of 4xx, the
lumen points lie inside the bounding box in no tet. Slow clients trickle their requests byte by byte, read their
replies slowly, or go away halfway (before the body, or before reading the reply), and some open a connection and
send nothing. A poller times GET /healthz all along. The service's resident memory and open file descriptors are read from its process
(found by its listening port). Everything stops by itself: the duration is capped and every socket has a timeout.
"""  # noqa: E501 -- argparse prints this docstring as it is (--help)

from __future__ import annotations

import argparse
import http.client
import json
import os
import random
import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from bench._report import Report
from studies import results
from tools.loadtest import loopback, read_reply

MAX_DURATION_S = 3600.0
LUMEN_MM = [0.0, -21.0, 40.0]  # inside the mesh's bounding box, in the rectal lumen: in no tet
SLOW_CHUNK_BYTES = 8  # a slow client sends its request this many bytes at a time


@dataclass
class Tally:
    """What the clients saw; appended to by many threads (list.append and Counter updates under the lock)."""

    latencies_ms: list[float] = field(default_factory=list)
    statuses: Counter = field(default_factory=Counter)
    slow: Counter = field(default_factory=Counter)  # slow and faulty clients: status or what they did
    health_ms: list[tuple[float, float]] = field(default_factory=list)  # (seconds since start, ms)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def count(self, status: int | str, ms: float | None = None) -> None:
        with self.lock:
            self.statuses[status] += 1
            if ms is not None:
                self.latencies_ms.append(ms)


def service_process(port: int):
    """The `python -m service` process listening on `port` (this machine), or SystemExit naming the port.

    With several workers the listening socket is seen in one worker: its parent is the one wanted.
    """
    import psutil

    for conn in psutil.net_connections(kind="tcp"):
        if conn.status == psutil.CONN_LISTEN and conn.laddr.port == port and conn.pid:
            process = psutil.Process(conn.pid)
            while (parent := process.parent()) is not None and _runs_service(parent):
                process = parent
            return process
    raise SystemExit(f"error: no process of this machine listens on port {port} (or it is not visible; pass --pid)")


def _runs_service(process) -> bool:
    command = process.cmdline()
    return any(a == "-m" and b == "service" for a, b in zip(command, command[1:]))


def usage(process) -> tuple[float, int]:
    """(resident memory MB, open file descriptors) of the process and its children (uvicorn workers)."""
    procs = [process, *process.children(recursive=True)]
    return sum(p.memory_info().rss for p in procs) / 2**20, sum(p.num_fds() for p in procs)


def requests_mix(model: dict, rng: random.Random, n: int, bad_share: float, lumen_share: float):
    """`n` (label, body bytes, headers) requests: good ones of each kind, bad ones, lumen-point ones."""
    env, regions, inside = model["envelope"], sorted(model["regions"]), model["inside_points"]
    binary, json_ = {"accept": "application/octet-stream"}, {"accept": "application/json"}
    out = []
    for _ in range(n):
        guide = {"displacement_mm": round(rng.uniform(*env["displacement_mm"]), 3),
                 "angle_deg": round(rng.uniform(*env["angle_deg"]), 3)}
        u = rng.random()
        if u < bad_share:
            out.append(_bad(rng, guide, env))
            continue
        if u < bad_share + lumen_share:
            points = [*rng.sample(inside, 5), LUMEN_MM]
            out.append(("lumen", {**guide, "points": points}, json_))
            continue
        kind = rng.choices(["full-binary", "full-json", "region", "points"], weights=[40, 10, 35, 15])[0]
        if kind == "region":
            out.append(("region", {**guide, "region": rng.choice(regions)}, rng.choice([binary, json_])))
        elif kind == "points":
            out.append(("points", {**guide, "points": rng.sample(inside, 50)}, json_))
        else:
            out.append((kind, guide, binary if kind == "full-binary" else json_))
    return [(label, body if isinstance(body, bytes) else json.dumps(body).encode(),
             {"content-type": "application/json", **headers}) for label, body, headers in out]


def _bad(rng: random.Random, guide: dict, env: dict):
    """One bad request: out of envelope, not finite, wrong type, unknown field or region, malformed, 415, 406."""
    kind = rng.randrange(8)
    if kind == 0:
        return "bad", {**guide, "displacement_mm": env["displacement_mm"][1] + 5.0}, {}
    if kind == 1:
        return "bad", b'{"displacement_mm": NaN, "angle_deg": 0}', {}
    if kind == 2:
        return "bad", {**guide, "angle_deg": "2"}, {}
    if kind == 3:
        return "bad", {**guide, "colour": "red"}, {}
    if kind == 4:
        return "bad", {**guide, "region": "liver"}, {}
    if kind == 5:
        return "bad", b'{"displacement_mm": 5, "angle_deg":', {}
    if kind == 6:
        return "bad", guide, {"content-type": "text/plain"}
    return "bad", guide, {"accept": "text/html"}


def client(host: str, port: int, mix: list, tally: Tally, stop: threading.Event, auth: dict) -> None:
    """A closed-loop client on one keep-alive connection (reconnecting after a failure)."""
    conn, buffer, k = http.client.HTTPConnection(host, port, timeout=30), bytearray(), 0
    while not stop.is_set():
        label, body, headers = mix[k % len(mix)]
        k += 1
        t0 = time.perf_counter()
        try:
            conn.request("POST", "/predict", body=body, headers={**headers, **auth})
            reply = conn.getresponse()
            read_reply(reply, buffer)
            tally.count(reply.status, (time.perf_counter() - t0) * 1e3 if reply.status == 200 else None)
        except (OSError, http.client.HTTPException) as exc:
            tally.count(f"connection error ({type(exc).__name__})")
            conn.close()
            conn = http.client.HTTPConnection(host, port, timeout=30)
    conn.close()


def slow_client(host: str, port: int, mix: list, tally: Tally, stop: threading.Event, auth: dict, seed: int) -> None:
    """Requests sent a few bytes at a time and replies read slowly; a quarter of them given up halfway."""
    rng = random.Random(seed)
    while not stop.is_set():
        label, body, headers = rng.choice(mix)
        head = "".join(f"{k}: {v}\r\n" for k, v in {**headers, **auth, "content-length": len(body),
                                                    "connection": "close"}.items())
        raw = f"POST /predict HTTP/1.1\r\nhost: {host}\r\n{head}\r\n".encode() + body
        fault = rng.choice(["none", "none", "idle", "leave-while-sending", "leave-before-reading", "oversize"])
        try:
            with socket.create_connection((host, port), timeout=30) as s:
                outcome = _slow_exchange(s, raw, fault, stop, rng)
        except OSError as exc:
            outcome = f"connection error ({type(exc).__name__})"
        with tally.lock:
            tally.slow[outcome] += 1


def _slow_exchange(s: socket.socket, raw: bytes, fault: str, stop: threading.Event, rng: random.Random) -> str:
    if fault == "idle":  # connect and say nothing for a while
        stop.wait(rng.uniform(2, 8))
        return "idle, then left"
    if fault == "oversize":  # announce a body over any sane limit: the service must refuse it unread
        s.sendall(b"POST /predict HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\ncontent-length: "
                  b"1000000000\r\n\r\n")
        return _status(s.recv(4096))
    end = len(raw) // 2 if fault == "leave-while-sending" else len(raw)
    for i in range(0, end, SLOW_CHUNK_BYTES):
        if stop.is_set():
            return "stopped"
        s.sendall(raw[i:i + SLOW_CHUNK_BYTES])
        time.sleep(0.01)
    if fault == "leave-while-sending":
        return "left while sending"
    first = s.recv(4096)
    if fault == "leave-before-reading":
        return "left before reading"
    while not stop.is_set() and s.recv(4096):  # slowly: 4 kB at a time
        time.sleep(0.005)
    return _status(first)


def _status(head: bytes) -> str:
    parts = head.split(b" ", 2)
    return parts[1].decode() if len(parts) > 1 and parts[1].isdigit() else "no reply"


def health_poller(host: str, port: int, tally: Tally, stop: threading.Event, t_start: float) -> None:
    conn = http.client.HTTPConnection(host, port, timeout=30)
    while not stop.is_set():
        t0 = time.perf_counter()
        try:
            conn.request("GET", "/healthz")
            reply = conn.getresponse()
            reply.read()
            ms = (time.perf_counter() - t0) * 1e3 if reply.status == 200 else float("inf")
        except (OSError, http.client.HTTPException):
            ms = float("inf")
            conn.close()
            conn = http.client.HTTPConnection(host, port, timeout=30)
        with tally.lock:
            tally.health_ms.append((t0 - t_start, ms))
        stop.wait(0.02)
    conn.close()


def model_for_mix(url: str, auth: dict, seed: int = 0) -> dict:
    """What the mix needs from GET /model and GET /mesh: envelope, regions, points inside the mesh."""
    host, port = loopback(url)
    conn = http.client.HTTPConnection(host, port, timeout=60)
    conn.request("GET", "/model", headers=auth)
    model = json.loads(conn.getresponse().read())
    conn.request("GET", "/mesh", headers=auth)
    mesh = json.loads(conn.getresponse().read())
    conn.close()
    nodes = np.asarray(mesh["nodes"])  # float32 values: the service takes them back as points (README)
    inside = nodes[np.random.default_rng(seed).choice(len(nodes), 2000, replace=False)].tolist()
    return {"envelope": model["envelope"], "regions": model["regions"], "inside_points": inside}


def run(url: str, *, duration_s: float, clients: int, slow_clients: int, warmup_s: float, process,
        token: str | None = None, seed: int = 0) -> dict:
    """Soak the service; returns every figure `report` prints.

    A warm-up with the same traffic comes first, and its clients leave before the start figures are
    read: the first requests open files that stay open (prometheus_client's files with several
    workers) and grow onnxruntime's buffers, and that is not what a leak looks like.
    """
    host, port = loopback(url)
    auth = {"authorization": f"Bearer {token}"} if token else {}
    rng = random.Random(seed)
    model = model_for_mix(url, auth, seed)
    mixes = [requests_mix(model, random.Random(rng.random()), 400, 0.05, 0.01) for _ in range(clients)]
    cold = usage(process)
    _traffic(host, port, mixes, slow_clients, auth, seed, duration_s=warmup_s, process=process)
    start = _settle(process)
    tally, samples, wall_s, left = _traffic(host, port, mixes, slow_clients, auth, seed,
                                            duration_s=min(duration_s, MAX_DURATION_S), process=process)
    return {"wall_s": wall_s, "tally": tally, "cold": cold, "start": start, "end": _settle(process, start[1]),
            "samples": samples, "clients_left": left}


def _traffic(host: str, port: int, mixes: list, slow_clients: int, auth: dict, seed: int, *, duration_s: float,
             process) -> tuple[Tally, list, float, int]:
    """Run the clients, slow clients and /healthz poller for `duration_s`, sampling the service's usage every
    10 s; then stop them all. Returns the tally, the (seconds, MB, fds) samples, the wall time and how many
    client threads failed to stop."""
    tally, stop = Tally(), threading.Event()
    t_start = time.perf_counter()
    threads = [threading.Thread(target=client, args=(host, port, mix, tally, stop, auth), daemon=True) for mix in mixes]
    threads += [threading.Thread(target=slow_client, daemon=True,
                                 args=(host, port, mixes[i % len(mixes)], tally, stop, auth, seed + i))
                for i in range(slow_clients)]
    threads.append(threading.Thread(target=health_poller, args=(host, port, tally, stop, t_start), daemon=True))
    for t in threads:
        t.start()
    samples, deadline = [], t_start + duration_s
    while (left := deadline - time.perf_counter()) > 0:
        stop.wait(min(10.0, left))
        samples.append((time.perf_counter() - t_start, *usage(process)))
    wall_s = time.perf_counter() - t_start
    stop.set()
    for t in threads:
        t.join(40)
    return tally, samples, wall_s, sum(t.is_alive() for t in threads)


def _settle(process, fds_target: int | None = None, wait_s: float = 30.0) -> tuple[float, int]:
    """Usage once the service has closed the clients' sockets: when the descriptors reach `fds_target`,
    or (without one) hold still for a second; at most `wait_s`."""
    deadline, last = time.monotonic() + wait_s, None
    while True:
        now = usage(process)
        done = now[1] <= fds_target if fds_target is not None else last is not None and now[1] == last[1]
        if done or time.monotonic() > deadline:
            return now
        last = now
        time.sleep(1.0 if fds_target is None else 0.5)


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m bench soak", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--duration", type=float, default=600.0,
                    help=f"seconds after the warm-up (at most {MAX_DURATION_S:.0f})")
    ap.add_argument("--warmup", type=float, default=20.0, help="seconds of the same traffic before the start figures")
    ap.add_argument("--clients", type=int, default=8, help="closed-loop clients (saturation)")
    ap.add_argument("--slow-clients", type=int, default=20)
    ap.add_argument("--pid", type=int, help="the service's process id (default: the process listening on the port)")
    ap.add_argument("--token", help="a bearer token, if the service asks for one")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    if not 0 < args.duration <= MAX_DURATION_S or not 1 <= args.clients <= 256 or not 0 <= args.slow_clients <= 256:
        ap.error(f"--duration must be in (0, {MAX_DURATION_S:.0f}], --clients 1..256, --slow-clients 0..256")
    _, port = loopback(args.url)
    import psutil

    process = psutil.Process(args.pid) if args.pid else service_process(port)
    load_before = os.getloadavg()
    print(f"soak: {args.duration:.0f} s (after {args.warmup:.0f} s warm-up) against {args.url} (pid {process.pid}); "
          f"{args.clients} clients, {args.slow_clients} slow clients, /healthz polled every 20 ms; "
          f"load average before {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}", flush=True)
    r = run(args.url, duration_s=args.duration, clients=args.clients, slow_clients=args.slow_clients,
                 warmup_s=args.warmup, process=process, token=args.token)
    say = Report()
    code = report(r, os.getloadavg(), say)
    print(f"wrote {results.write('bench_soak', {'lines': say.lines, 'targets_met': code == 0}, publish=args.publish)}")
    return code


def report(r: dict, load_after, say=print) -> int:
    tally = r["tally"]
    lat = np.asarray(tally.latencies_ms) if tally.latencies_ms else np.array([np.nan])
    total = sum(tally.statuses.values())
    say(f"requests: {total} in {r['wall_s']:.0f} s = {total / r['wall_s']:.0f} req/s; 200 latency ms "
          f"p50 {np.percentile(lat, 50):.2f} p99 {np.percentile(lat, 99):.2f} max {lat.max():.1f}")
    say("  by status: " + ", ".join(f"{k}: {v}" for k, v in sorted(tally.statuses.items(), key=str)))
    say("  slow and faulty clients: " + ", ".join(f"{k}: {v}" for k, v in sorted(tally.slow.items(), key=str)))
    t, ms = (np.array(x) for x in zip(*tally.health_ms))
    minutes = [ms[(t >= m) & (t < m + 60)] for m in range(0, int(max(t.max(), 1)) + 1, 60)]
    per_minute = [float(np.percentile(x, 99)) for x in minutes if len(x)]
    say(f"/healthz: {len(ms)} polls, p50 {np.percentile(ms, 50):.2f} ms, p99 {np.percentile(ms, 99):.2f} ms, "
          f"max {ms.max():.1f} ms; p99 per minute {' '.join(f'{x:.1f}' for x in per_minute)}")
    (cold_mb, cold_fds), (start_mb, start_fds), (end_mb, end_fds) = r["cold"], r["start"], r["end"]
    peak_mb, peak_fds = max(s[1] for s in r["samples"]), max(s[2] for s in r["samples"])
    say(f"RSS MB: before any traffic {cold_mb:.0f}, start (after the warm-up, its clients gone) {start_mb:.0f}, "
          f"peak {peak_mb:.0f}, end {end_mb:.0f} ({100 * (end_mb / start_mb - 1):+.1f} % of start)")
    say(f"open file descriptors: before any traffic {cold_fds}, start {start_fds}, peak {peak_fds}, "
          f"end (clients gone) {end_fds}")
    say(f"load average after {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}; "
          f"client threads still running: {r['clients_left']}")
    five = sum(v for k, v in [*tally.statuses.items(), *tally.slow.items()] if str(k).startswith("5"))
    checks = {"no 5xx": five == 0, "RSS within 10 % of its start": abs(end_mb / start_mb - 1) <= 0.10,
              "file descriptors back to baseline": end_fds <= start_fds,
              "/healthz p99 <= 20 ms in every minute": max(per_minute) <= 20.0}
    say("targets: " + "; ".join(f"{name}: {'met' if ok else 'MISSED'}" for name, ok in checks.items()))
    return 0 if all(checks.values()) else 1
