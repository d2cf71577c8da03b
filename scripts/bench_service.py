"""Service throughput and latency with dynamic batching off and on, and with 1 or more uvicorn workers, in one run.

    python scripts/bench_service.py --model models/default --model runs/paper/model [--duration 5] [--workers 1 2]

For each model and each configuration (batching off/on x workers), starts `python -m service` on a
free loopback port and loads it with service/loadtest.py for each scenario (target, reply format,
clients). Prints one markdown table (with the mean batch size the service reports in /metrics),
the in-process decode time alone and in a batch of 8, and the issue #12 targets.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from service import loadtest
from service.model import Predictor, read_model_folder
from service.settings import DEFAULT_MODEL

SCENARIOS = [(None, "binary", 1), (None, "binary", 8), (None, "json", 8), ("markers", "json", 1), ("markers", "binary", 8)]


def decode_ms(predictor: Predictor, batch: int, n: int = 200) -> float:
    """Median wall time per request of a full-mesh decode plus adding the reference positions, in batches of `batch`."""
    env = predictor.manifest.envelope
    rng = np.random.default_rng(0)
    guides = np.column_stack([rng.uniform(*env.displacement_mm, (n, batch)).ravel(),
                              rng.uniform(*env.angle_deg, (n, batch)).ravel()]).reshape(n, batch, 2)
    times = []
    for g in guides:
        t0 = time.perf_counter()
        _ = predictor.decode(g) + predictor.nodes32
        times.append((time.perf_counter() - t0) * 1e3 / batch)
    return float(np.median(times[5:]))


def run_config(model: Path, *, batching: bool, workers: int, duration_s: float) -> list[dict]:
    flags = ["--model", str(model), "--batching", str(batching).lower(), "--workers", str(workers)]
    rows = []
    with loadtest.local_service(*flags, wait_s=120) as url:
        for region, fmt, clients in SCENARIOS:
            before = loadtest.batch_counts(url)
            s = loadtest.run(url, concurrency=clients, duration_s=duration_s, fmt=fmt, region=region).summary()
            batches, requests = np.subtract(loadtest.batch_counts(url), before)
            rows.append({"batching": batching, "workers": workers, "region": region or "full", "format": fmt,
                         "clients": clients, **s, "mean_batch": requests / batches if batches else None})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, action="append", help="a model folder (repeat for several)")
    ap.add_argument("--duration", type=float, default=5.0, help="seconds per scenario")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="uvicorn worker counts to compare")
    ap.add_argument("--json-out", type=Path, help="also write the figures as JSON")
    args = ap.parse_args()
    models = args.model or [DEFAULT_MODEL]

    print(f"load average at start {os.getloadavg()[0]:.2f}; {os.cpu_count()} cores shared by service and clients; "
          f"{args.duration:g} s per scenario; onnxruntime 1 thread per worker")
    results = {}
    for model in models:
        folder = read_model_folder(model)
        predictor = Predictor(folder)
        solo, batched = decode_ms(predictor, 1), decode_ms(predictor, 8)
        del predictor
        rows = [row for workers in args.workers for batching in (False, True)
                for row in run_config(model, batching=batching, workers=workers, duration_s=args.duration)]
        results[str(model)] = {"n_nodes": len(folder.nodes), "rank": folder.manifest.pca.rank,
                               "decode_ms_solo": solo, "decode_ms_in_batch_of_8": batched, "rows": rows}
        print(f"\nmodel {model}: {len(folder.nodes)} nodes, rank {folder.manifest.pca.rank}; in process, full mesh: "
              f"{solo:.3f} ms per request alone, {batched:.3f} ms per request in a batch of 8")
        print("| batching | workers | region | format | clients | p50 ms | p95 ms | p99 ms | max ms | req/s | errors | mean batch |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            mean = f"{r['mean_batch']:.1f}" if r["mean_batch"] else ""
            print(f"| {'on' if r['batching'] else 'off'} | {r['workers']} | {r['region']} | {r['format']} | "
                  f"{r['clients']} | {r['p50_ms']:.2f} | {r['p95_ms']:.2f} | {r['p99_ms']:.2f} | {r['max_ms']:.2f} | "
                  f"{r['throughput_rps']:.0f} | {r['errors']} | {mean} |")
    print(f"\nload average at end {os.getloadavg()[0]:.2f}")
    print_targets(results)
    if args.json_out:
        args.json_out.write_text(json.dumps(results, indent=2))
    return 0


def print_targets(results: dict) -> None:
    """Issue #12 §2, full mesh, binary: the largest model with 8 clients against today's service (batching off,
    1 worker), and the smallest model with 1 client, batching on against off for the same workers."""
    def row(model: str, batching: bool, workers: int, clients: int) -> dict:
        return next(r for r in results[model]["rows"] if r["batching"] == batching and r["workers"] == workers
                    and r["region"] == "full" and r["format"] == "binary" and r["clients"] == clients)

    big = max(results, key=lambda m: results[m]["n_nodes"])
    small = min(results, key=lambda m: results[m]["n_nodes"])
    workers = sorted({r["workers"] for r in results[big]["rows"]})
    today = row(big, False, workers[0], 8)
    for w in workers:
        on = row(big, True, w, 8)
        print(f"target ({results[big]['n_nodes']} nodes, 8 clients): batching on, {w} worker(s): "
              f"{on['throughput_rps']:.0f} req/s = {on['throughput_rps'] / today['throughput_rps']:.1f}x batching off with "
              f"{workers[0]} ({today['throughput_rps']:.0f} req/s; target >= 4x); p99 {on['p99_ms']:.1f} ms (target <= 40 ms)")
    for w in workers:
        on, off = row(small, True, w, 1), row(small, False, w, 1)
        print(f"target ({results[small]['n_nodes']} nodes, 1 client, {w} worker(s)): p99 {on['p99_ms']:.2f} ms with "
              f"batching vs {off['p99_ms']:.2f} ms without (target: no worse)")


if __name__ == "__main__":
    sys.exit(main())
