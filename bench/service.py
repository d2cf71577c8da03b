"""Service throughput and latency, batching off and on, with the service pinned to 1 and to all usable cores.

    python -m bench service [--duration 3] [--repeats 3] [--model models/default --model runs/paper_decoder/model] [--publish]

For each core set (the service pinned with taskset; on more than one core the clients, this
process's threads, are pinned to the other cores where there are any, else share them), each
model and each configuration (batching off with the default workers, off with one worker per
core, on with the defaults), starts `python -m service` on a free loopback port and loads it with
tools/loadtest.py for each scenario. The paper-scale decoder (bench/paper_decoder.py) is built
into runs/ first when missing. Beside the served figures it measures, pinned to the same cores:
the in-process decode capacity (onnxruntime, batches of 8, the best of three lane and thread counts) and the
per-request work outside onnxruntime (reference positions, reply bodies), alone; and in every row the CPU
that the service's processes (user and system, from /proc) and the clients spent per request, so the gap
between served and in-process figures is accounted for (bench/service_targets.py's cpu_rows). With a 312k-node
JSON load it polls /healthz from another process (the event loop must stay free). Prints the tables and the issue #35
targets; writes everything, with the machine it ran on, through studies.results.
"""  # noqa: E501 -- argparse prints this docstring as it is (--help)

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np

from contracts.model import read_manifest
from service.cores import Concurrency, basis_bytes, usable_cores
from service.settings import DEFAULT_MODEL
from studies import results
from tools import loadtest

from . import paper_decoder

# (name, region, format, clients) per model size; the large model's JSON row also polls /healthz
SMALL = [("markers binary 1", "markers", "binary", 1), ("full binary 1", None, "binary", 1),
         ("full binary 8", None, "binary", 8)]
LARGE = [("full binary 1", None, "binary", 1), ("full binary 8", None, "binary", 8),
         ("full json 8", None, "json", 8)]
LARGE_NODES = 100_000
# CPU ms per request of a row's timed part (run_scenario): the service's processes, then the clients
CPU_FIELDS = ("service_user_ms", "service_sys_ms", "client_user_ms", "client_sys_ms")


def core_sets() -> list[set[int]]:
    """One core for the service (the last usable one), then all usable cores."""
    cores = sorted(os.sched_getaffinity(0))
    return [{cores[-1]}, set(cores)] if len(cores) > 1 else [set(cores)]


def configs(n_cores: int) -> list[tuple[str, list[str]]]:
    off = [("off", ["--batching", "false"])]
    if n_cores > 1:
        off.append((f"off, {n_cores} workers", ["--batching", "false", "--workers", str(n_cores)]))
    return [*off, ("on", ["--batching", "true"])]


# /healthz polled from its own process: a thread beside the load's 8 client threads would wait for their GIL, and
# time that wait as the service's
POLLER = """
import json, sys, threading, time, urllib.request
stop, out = threading.Event(), []
threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
print("polling", flush=True)
while not stop.is_set():
    t0 = time.perf_counter()
    urllib.request.urlopen(sys.argv[1] + "/healthz", timeout=10).read()
    out.append((time.perf_counter() - t0) * 1e3)
    stop.wait(0.005)
print(json.dumps(out), flush=True)
"""


@contextmanager
def health_poller(url: str):
    """GET /healthz every 5 ms from another process (on this one's cores) for the block; the latencies (ms) are in
    the yielded list once the block ends."""
    out: list[float] = []
    proc = subprocess.Popen([sys.executable, "-c", POLLER, url], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True)
    try:
        proc.stdout.readline()  # started
        yield out
    finally:
        text, _ = proc.communicate("", timeout=60)
        out.extend(json.loads(text.strip().splitlines()[-1]) if text.strip() else [])


def run_scenario(url: str, scenario, duration_s: float, *, large: bool, pid: int | None = None) -> dict:
    """One load run; with the service's `pid`, also the CPU that the service (every worker) and the clients (this
    process's threads) spent per request in its timed part."""
    name, region, fmt, clients = scenario
    before, cpu = loadtest.batch_counts(url), {}

    def read_cpu(at: str) -> None:
        service = loadtest.cpu_seconds(pid) if pid is not None else None
        if service is not None:
            mine = os.times()
            cpu[at] = (*service, mine.user, mine.system)

    with health_poller(url) if large and fmt == "json" else nullcontext([]) as health:
        result = loadtest.run(url, concurrency=clients, duration_s=duration_s, fmt=fmt, region=region, warmup=5,
                              on_start=lambda: read_cpu("start"))
        read_cpu("end")
    s = result.summary()
    batches, requests = np.subtract(loadtest.batch_counts(url), before)
    row = {"scenario": name, "region": region or "full", "format": fmt, "clients": clients, **s,
           "mean_batch": requests / batches if batches else None}
    if len(cpu) == 2 and s["requests"]:
        spent = np.subtract(cpu["end"], cpu["start"]) * 1e3 / s["requests"]
        row.update(zip(CPU_FIELDS, map(float, spent)))
    if health:
        row["healthz_p99_ms"], row["healthz_polls"] = float(np.percentile(health, 99)), len(health)
    return row


def client_cores(service: set[int]) -> set[int]:
    others = set(os.sched_getaffinity(0)) - service
    return others or service


def served(model: Path, cores: set[int], duration_s: float, *, large: bool, repeats: int = 1,
           candidates: list[tuple[str, list[str]]] | None = None, scenarios: list[tuple] | None = None) -> list[dict]:
    """Each configuration (`configs` unless `candidates` are given, as (name, service flags)) and scenario
    `repeats` times, the configurations taking turns (so a slow spell of a shared machine falls on all of them),
    reduced to one row each by `median_row`."""
    runs, mine = {}, os.sched_getaffinity(0)
    share = not (mine - cores)  # the clients run on the service's cores
    os.sched_setaffinity(0, client_cores(cores))
    try:
        for _ in range(repeats):
            for config, flags in candidates or configs(len(cores)):
                with loadtest.local_service_process("--model", str(model), *flags, "--access-log", "off", wait_s=180,
                                                    cpus=cores) as (url, server):
                    for scenario in scenarios or (LARGE if large else SMALL):
                        row = {"cores": len(cores), "config": config, "clients_share_cores": share,
                               **run_scenario(url, scenario, duration_s, large=large, pid=server.pid)}
                        runs.setdefault((config, scenario[0]), []).append(row)
                        if repeats > 1:
                            print_row(row, prefix="run ")
    finally:
        os.sched_setaffinity(0, mine)
    rows = [median_row(r) for r in runs.values()]
    for row in rows:
        print_row(row)
    return rows


def median_row(runs: list[dict]) -> dict:
    """One row from repeated runs of a configuration and scenario: the median of each figure, the requests and
    errors summed, the runs' throughputs kept."""
    row = dict(runs[0])
    for key, value in runs[0].items():
        if isinstance(value, float) or key == "mean_batch":
            values = [r[key] for r in runs if r.get(key) is not None]
            row[key] = float(np.median(values)) if values else None
    row["requests"], row["errors"] = sum(r["requests"] for r in runs), sum(r["errors"] for r in runs)
    row["repeats"], row["throughput_runs_rps"] = len(runs), [r["throughput_rps"] for r in runs]
    return row


def in_process(model: Path, cores: set[int]) -> dict:
    """Pinned to `cores`: the decode capacity, the best of the default workers, lanes and threads (each worker's
    lanes as threads of this process), one lane on every core and a lane per core of one thread each, so it does
    not depend on the defaults; and the work outside onnxruntime."""
    from service.model import Predictor, read_model_folder
    from service.predict.decode import ALL_NODES, Query, finish
    from service.predict.replies import binary_reply, json_chunks

    mine = os.sched_getaffinity(0)
    os.sched_setaffinity(0, cores)
    try:
        c = Concurrency.for_model(len(cores), basis_bytes(model))
        folder = read_model_folder(model)
        predictor = Predictor(folder, threads=c.threads)
        guides = np.tile([[5.0, 2.0]], (8, 1))
        solo = _median_ms(lambda: predictor.decode(guides[:1]))
        lone = _lone_ms(lambda: predictor.decode(guides[:1]))
        u = predictor.decode(guides[:1])[0]
        query = Query((5.0, 2.0), ALL_NODES, None)
        add = _median_ms(lambda: finish(predictor, query, u.copy()))
        copy = _median_ms(lambda: u.copy())
        prediction = finish(predictor, query, u.copy())
        binary = _median_ms(lambda: binary_reply(prediction.positions))
        json_ms = _median_ms(lambda: json_chunks({"count": len(u)}, {"positions": prediction.positions}), n=5)
        capacity = {}
        for lanes, threads in sorted({(c.workers * c.lanes, c.threads), (1, len(cores)), (len(cores), 1)}):
            p = predictor if threads == c.threads else Predictor(folder, threads=threads)
            capacity[f"{lanes} lane(s) x {threads} thread(s)"] = _capacity(p, guides, lanes=lanes)
    finally:
        os.sched_setaffinity(0, mine)
    return {"cores": len(cores), "defaults": c.__dict__, "decode_ms_batch_1": solo,
            "decode_lone_p50_ms": lone[0], "decode_lone_p99_ms": lone[1],
            "reference_positions_ms": max(add - copy, 0.0), "binary_reply_ms": binary, "json_reply_ms": json_ms,
            "decode_capacity_rps": max(capacity.values()), "decode_capacity_by_config_rps": capacity}


def _median_ms(f, n: int = 20) -> float:
    f()
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        f()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def _lone_ms(f, n: int = 300, gap_s: float = 0.001) -> tuple[float, float]:
    """p50 and p99 (ms) of `f` called `gap_s` apart, as a lone client's decodes come: onnxruntime's sleeping threads
    wake for each call. A served lone request can be no faster than this."""
    f()
    times = []
    for _ in range(n):
        time.sleep(gap_s)
        t0 = time.perf_counter()
        f()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times)), float(np.percentile(times, 99))


def _capacity(predictor, guides: np.ndarray, *, lanes: int, seconds: float = 1.5) -> float:
    """Requests a second decoded in batches of len(guides) by `lanes` threads at once."""
    done, stop_at = [0] * lanes, time.perf_counter() + seconds

    def lane(i: int) -> None:
        while time.perf_counter() < stop_at:
            predictor.decode(guides)
            done[i] += len(guides)

    t0 = time.perf_counter()
    threads = [threading.Thread(target=lane, args=(i,)) for i in range(lanes)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return sum(done) / (time.perf_counter() - t0)


def print_row(r: dict, prefix: str = "") -> None:
    mean = f"{r['mean_batch']:.1f}" if r.get("mean_batch") else ""
    health = f"{r['healthz_p99_ms']:.1f}" if "healthz_p99_ms" in r else ""
    print(f"{prefix}| {r['cores']} | {r['config']} | {r['scenario']} | {r['p50_ms']:.2f} | {r['p99_ms']:.2f} | "
          f"{r['throughput_rps']:.0f} | {r['errors']} | {mean} | {health} |", flush=True)


def versions() -> dict[str, str]:
    """The versions of what serves: Python and the service's packages."""
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": sys.version.split()[0]}
    for name in ("onnxruntime", "numpy", "uvicorn", "uvloop", "httptools", "fastapi", "starlette", "orjson"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    return out


def add_run_flags(ap: argparse.ArgumentParser) -> None:
    """The flags the service benchmarks share: --model (repeatable), --duration, --repeats and --publish."""
    ap.add_argument("--model", type=Path, action="append",
                    help=f"a model folder (repeat); default {DEFAULT_MODEL.name} and {paper_decoder.PAPER_DECODER}")
    ap.add_argument("--duration", type=float, default=3.0, help="seconds per run of a row")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each row, the configurations taking turns; "
                    "the row is their median (default 3)")
    results.add_publish_flag(ap)


def model_name(model: Path) -> str:
    """A model folder as a result names it: relative to the repository (a committed result holds no machine's
    paths), or as given when it lies outside."""
    path = Path(model).resolve()
    return path.relative_to(results.ROOT).as_posix() if path.is_relative_to(results.ROOT) else str(model)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench service", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_flags(ap)
    args = ap.parse_args(argv)
    models = args.model or [DEFAULT_MODEL, paper_decoder.ensure()]
    if args.repeats < 1:
        ap.error("--repeats: at least 1")
    print(f"{usable_cores()} usable cores; load average {os.getloadavg()[0]:.2f}; {args.duration:g} s per run, "
          f"the median of {args.repeats} run(s) per row")
    data = {"duration_s": args.duration, "repeats": args.repeats, "load_at_start": os.getloadavg()[0],
            "versions": versions(), "models": {}}
    for model in models:
        n_nodes = read_manifest(model).mesh.n_nodes
        large = n_nodes >= LARGE_NODES
        entry = {"n_nodes": n_nodes, "rank": read_manifest(model).pca.rank, "in_process": [], "rows": []}
        print(f"\nmodel {model}: {n_nodes} nodes\n| cores | batching | scenario | p50 ms | p99 ms | req/s | errors "
              "| mean batch | /healthz p99 ms |\n|---|---|---|---|---|---|---|---|---|")
        for cores in core_sets():
            entry["in_process"].append(in_process(model, cores))
            entry["rows"] += served(model, cores, args.duration, large=large, repeats=args.repeats)
        for p in entry["in_process"]:
            print(f"in process, {p['cores']} core(s): decode {p['decode_ms_batch_1']:.3f} ms back to back, "
                  f"p50 {p['decode_lone_p50_ms']:.3f} and p99 {p['decode_lone_p99_ms']:.3f} ms 1 ms apart; capacity "
                  f"{p['decode_capacity_rps']:.0f} req/s; outside onnxruntime: reference positions "
                  f"{p['reference_positions_ms']:.3f} ms, binary reply {p['binary_reply_ms']:.4f} ms, "
                  f"JSON reply {p['json_reply_ms']:.2f} ms")
        data["models"][model_name(model)] = entry
    data["load_at_end"] = os.getloadavg()[0]
    from .service_targets import cpu_rows, readme_rows, targets

    data["targets"], data["cpu"], data["readme_rows"] = targets(data), cpu_rows(data), readme_rows(data)
    print()
    for c in data["cpu"]:
        print(f"{c['cores']} core(s), the large model batched, CPU ms a request: decode alone {c['decode_ms']}, "
              f"service {c['service_user_ms']} user + {c['service_sys_ms']} sys, clients {c['client_ms']}"
              f"{' (on the same cores)' if c['clients_share_cores'] else ''}; bound {c['bound_rps']:.0f} req/s, "
              f"served {c['served_rps']:.0f} ({c['busy']:.0%} busy)")
    for t in data["targets"]:
        print(f"target: {t['target']}: {t['value']} -> {'met' if t['met'] else 'NOT met'}")
    print(f"\nwrote {results.write('bench_service', data, publish=args.publish)}")
    return 0
