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
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from service import soak
from service.loadtest import loopback

from bench._report import Report
from studies import results


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m bench soak", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--duration", type=float, default=600.0, help=f"seconds after the warm-up (at most {soak.MAX_DURATION_S:.0f})")
    ap.add_argument("--warmup", type=float, default=20.0, help="seconds of the same traffic before the start figures")
    ap.add_argument("--clients", type=int, default=8, help="closed-loop clients (saturation)")
    ap.add_argument("--slow-clients", type=int, default=20)
    ap.add_argument("--pid", type=int, help="the service's process id (default: the process listening on the port)")
    ap.add_argument("--token", help="a bearer token, if the service asks for one")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    if not 0 < args.duration <= soak.MAX_DURATION_S or not 1 <= args.clients <= 256 or not 0 <= args.slow_clients <= 256:
        ap.error(f"--duration must be in (0, {soak.MAX_DURATION_S:.0f}], --clients 1..256, --slow-clients 0..256")
    _, port = loopback(args.url)
    import psutil

    process = psutil.Process(args.pid) if args.pid else soak.service_process(port)
    load_before = os.getloadavg()
    print(f"soak: {args.duration:.0f} s (after {args.warmup:.0f} s warm-up) against {args.url} (pid {process.pid}); "
          f"{args.clients} clients, {args.slow_clients} slow clients, /healthz polled every 20 ms; "
          f"load average before {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}", flush=True)
    r = soak.run(args.url, duration_s=args.duration, clients=args.clients, slow_clients=args.slow_clients,
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
