"""Load-test a running service on loopback: N clients for T seconds (or R requests), JSON or binary.

    python -m tools.loadtest --url http://127.0.0.1:8000 --concurrency 8 --duration 10 --format binary
    python -m tools.loadtest --region markers --requests 2000

Each client holds one keep-alive connection and sends random (displacement, angle) inside the
model's envelope (read from GET /model). Prints p50/p95/p99/max latency, throughput and errors.
Refuses non-loopback hosts; stops by itself (duration capped at 300 s, requests at 1e6).
"""

from __future__ import annotations

import argparse
import http.client
import ipaddress
import json
import os
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Callable
from urllib.parse import urlparse

import numpy as np

MAX_DURATION_S = 300.0
MAX_REQUESTS = 1_000_000


class WarmUpFailed(RuntimeError):
    """A warm-up request got no 200: the load is not started (rather than waiting for it forever)."""


@dataclass
class Result:
    latencies_ms: np.ndarray
    errors: int
    wall_s: float

    def summary(self) -> dict:
        lat = self.latencies_ms if len(self.latencies_ms) else np.array([np.nan])
        return {"requests": int(len(self.latencies_ms) + self.errors), "errors": self.errors,
                "throughput_rps": len(self.latencies_ms) / self.wall_s if self.wall_s else 0.0,
                "p50_ms": float(np.percentile(lat, 50)), "p95_ms": float(np.percentile(lat, 95)),
                "p99_ms": float(np.percentile(lat, 99)), "max_ms": float(lat.max())}


def loopback(url: str) -> tuple[str, int]:
    parsed = urlparse(url)
    host, port = parsed.hostname or "", parsed.port or 80
    try:
        ok = all(ipaddress.ip_address(info[4][0]).is_loopback for info in socket.getaddrinfo(host, port))
    except (socket.gaierror, ValueError):
        ok = False
    if parsed.scheme != "http" or not ok:
        raise SystemExit(f"error: --url must be http:// on a loopback address (127.0.0.1, localhost, ::1), got {url!r}")
    return host, port


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def local_service(*flags: str, cwd: Path | None = None, wait_s: float = 30.0, cpus: set[int] | None = None):
    """Run `python -m service *flags` on a free loopback port for the block; yield its URL once /readyz answers.

    `cpus`: pin the service (every worker) to these cores, as `taskset` does."""
    with local_service_process(*flags, cwd=cwd, wait_s=wait_s, cpus=cpus) as (url, _):
        yield url


@contextmanager
def local_service_process(*flags: str, cwd: Path | None = None, wait_s: float = 30.0, cpus: set[int] | None = None):
    """As `local_service`, yielding (URL, the service's process): its pid is the one `cpu_seconds` reads."""
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    pin = ["taskset", "-c", ",".join(map(str, sorted(cpus)))] if cpus else []
    server = subprocess.Popen([*pin, sys.executable, "-m", "service", *flags, "--port", str(port),
                               "--log-level", "warning"],
                              cwd=cwd, env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        deadline = time.monotonic() + wait_s
        while True:
            try:
                urllib.request.urlopen(f"{url}/readyz", timeout=1)
                break
            except OSError:
                if time.monotonic() > deadline or server.poll() is not None:
                    raise SystemExit(f"error: the service did not become ready in {wait_s:.0f} s") from None
                time.sleep(0.25)
        yield url, server
    finally:
        server.terminate()
        server.wait(10)


def cpu_seconds(pid: int) -> tuple[float, float] | None:
    """(user, system) CPU seconds used so far by process `pid` and every process below it (uvicorn's workers), by
    psutil (the dev extra; bench only); None when there is no such process."""
    import psutil

    try:
        root = psutil.Process(pid)
        tree = [root, *root.children(recursive=True)]
    except psutil.Error:
        return None
    user = system = 0.0
    for process in tree:
        try:
            times = process.cpu_times()
        except psutil.Error:  # ended meanwhile
            continue
        user, system = user + times.user, system + times.system
    return user, system


def batch_counts(url: str) -> tuple[float, float]:
    """(batches, requests batched) so far, from the service's /metrics (one worker's, if it has several)."""
    text = urllib.request.urlopen(f"{url}/metrics", timeout=10).read().decode()
    values = {}
    for line in text.splitlines():
        name, _, value = line.partition(" ")
        if name in ("predict_batch_size_count", "predict_batch_size_sum"):
            values[name] = float(value)
    return values.get("predict_batch_size_count", 0.0), values.get("predict_batch_size_sum", 0.0)


def _bodies(envelope: dict, region: str | None, n: int, seed: int, extra: dict | None = None) -> list[bytes]:
    rng = np.random.default_rng(seed)
    (d0, d1), (a0, a1) = envelope["displacement_mm"], envelope["angle_deg"]
    out = []
    for d, a in zip(rng.uniform(d0, d1, n), rng.uniform(a0, a1, n)):
        body = {"displacement_mm": round(float(d), 4), "angle_deg": round(float(a), 4), **(extra or {})}
        if region:
            body["region"] = region
        out.append(json.dumps(body).encode())
    return out


def read_reply(reply: http.client.HTTPResponse, buffer: bytearray) -> int:
    """Read the whole reply body into `buffer` (grown as needed); its length.

    Reading into one buffer per client, rather than a new bytes object per reply, keeps the client's
    cost per megabyte low: a 3.7 MB reply read into fresh memory costs the client more than the decode.
    """
    if reply.length is None:  # chunked: no size to read into
        body = reply.read()
        return len(body)
    if len(buffer) < reply.length:
        buffer.extend(bytes(reply.length - len(buffer)))
    view, got = memoryview(buffer), 0
    while got < reply.length:
        n = reply.readinto(view[got:reply.length])
        if not n:
            raise http.client.IncompleteRead(bytes(view[:got]), reply.length - got)
        got += n
    return got


def run(url: str, *, concurrency: int = 1, duration_s: float | None = 10.0, requests: int | None = None,
        fmt: str = "json", region: str | None = None, warmup: int = 20, seed: int = 0,
        extra: dict | None = None, on_start: Callable[[], None] | None = None) -> Result:
    """Drive the service; latency is from sending the request to having the whole reply body. `extra`: more
    fields for every request body (points, materials). `on_start` is called once every client has warmed up, as
    the timed part begins (bench/service.py reads the CPU counters there)."""
    host, port = loopback(url)
    probe = http.client.HTTPConnection(host, port, timeout=10)
    probe.request("GET", "/model")
    envelope = json.loads(probe.getresponse().read())["envelope"]
    probe.close()
    headers = {"content-type": "application/json",
               "accept": "application/octet-stream" if fmt == "binary" else "application/json"}
    span = min(duration_s or MAX_DURATION_S, MAX_DURATION_S)
    budget = [min(requests or MAX_REQUESTS, MAX_REQUESTS)]
    lock = threading.Lock()
    latencies: list[list[float]] = [[] for _ in range(concurrency)]
    errors = [0] * concurrency

    def client(i: int) -> None:
        conn = http.client.HTTPConnection(host, port, timeout=30)
        bodies = _bodies(envelope, region, 512, seed + i, extra)
        buffer = bytearray()
        try:
            for k in range(warmup):
                conn.request("POST", "/predict", body=bodies[k % 512], headers=headers)
                reply = conn.getresponse()
                n = read_reply(reply, buffer)
                if reply.status != 200:
                    raise WarmUpFailed(f"HTTP {reply.status}: {bytes(buffer[:min(n, 300)]).decode(errors='replace')}")
        except (OSError, http.client.HTTPException, WarmUpFailed) as exc:
            warmup_failures.append(exc)
            start.abort()  # the others (and run) stop waiting at the barrier
            return
        try:
            start.wait()
        except threading.BrokenBarrierError:
            return
        k = 0
        while time.perf_counter() < deadline_at[0]:
            with lock:
                if budget[0] <= 0:
                    break
                budget[0] -= 1
            t0 = time.perf_counter()
            try:
                conn.request("POST", "/predict", body=bodies[k % 512], headers=headers)
                reply = conn.getresponse()
                read_reply(reply, buffer)
                ok = reply.status == 200
            except (OSError, http.client.HTTPException):
                ok = False
                conn.close()
                conn = http.client.HTTPConnection(host, port, timeout=30)
            dt = (time.perf_counter() - t0) * 1e3
            if ok:
                latencies[i].append(dt)
            else:
                errors[i] += 1
            k += 1
        conn.close()

    deadline_at = [time.perf_counter() + 2 * MAX_DURATION_S]  # set for real once every client has warmed up
    start = threading.Barrier(concurrency + 1)
    warmup_failures: list[Exception] = []
    threads = [threading.Thread(target=client, args=(i,), daemon=True) for i in range(concurrency)]
    for t in threads:
        t.start()
    try:
        start.wait()  # every client has warmed up
    except threading.BrokenBarrierError:
        raise WarmUpFailed(f"a warm-up request to {url} failed: {warmup_failures[0]}") from None
    t0 = time.perf_counter()
    if on_start is not None:
        on_start()
    deadline_at[0] = t0 + span
    for t in threads:
        t.join()
    return Result(np.concatenate([np.asarray(x) for x in latencies]), sum(errors), time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.loadtest", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--concurrency", type=int, default=1)
    ap.add_argument("--duration", type=float, default=10.0, help=f"seconds (at most {MAX_DURATION_S:.0f})")
    ap.add_argument("--requests", type=int, help="stop after this many requests")
    ap.add_argument("--format", choices=("json", "binary"), default="json")
    ap.add_argument("--region", help="decode one region (default: the full mesh)")
    args = ap.parse_args(argv)
    if not 1 <= args.concurrency <= 256:
        ap.error("--concurrency must be from 1 to 256")
    if args.duration <= 0 or (args.requests is not None and args.requests < 1):
        ap.error("--duration and --requests must be positive")
    try:
        result = run(args.url, concurrency=args.concurrency, duration_s=args.duration, requests=args.requests,
                     fmt=args.format, region=args.region)
    except ConnectionRefusedError:
        print(f"error: nothing listens on {args.url}; start it with `make serve`", file=sys.stderr)
        return 2
    except WarmUpFailed as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    s = result.summary()
    print(f"{args.region or 'full mesh'} {args.format} c={args.concurrency}: {s['requests']} requests, "
          f"{s['errors']} errors, {s['throughput_rps']:.0f} req/s; latency ms p50 {s['p50_ms']:.2f} "
          f"p95 {s['p95_ms']:.2f} p99 {s['p99_ms']:.2f} max {s['max_ms']:.2f}")
    return 1 if s["errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
