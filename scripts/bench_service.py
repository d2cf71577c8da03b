"""Service latency against a direct onnxruntime call for the same request, in one run.

    python scripts/bench_service.py --model models/default [--duration 5]

Starts `python -m service` on a free loopback port, loads it with service/loadtest.py for each
scenario, and times the in-process Predictor (onnxruntime) for the same full-mesh and markers
decodes. Prints a markdown table with medians, p99 and the service/onnxruntime ratio.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from service import loadtest
from service.model import Predictor, read_model_folder
from service.settings import DEFAULT_MODEL


def _direct_ms(predictor: Predictor, nodes, n: int = 2000) -> np.ndarray:
    """Per-call time of the decode alone, plus adding the reference positions (what /predict returns)."""
    rng = np.random.default_rng(0)
    env = predictor.manifest["envelope"]
    d = rng.uniform(*env["displacement_mm"], n)
    a = rng.uniform(*env["angle_deg"], n)
    ref = predictor.nodes32 if nodes is None else predictor.nodes32[nodes]
    out = []
    for i in range(n):
        t0 = time.perf_counter()
        _ = ref + predictor.displacement(d[i], a[i], nodes)
        out.append((time.perf_counter() - t0) * 1e3)
    return np.asarray(out[50:])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    ap.add_argument("--duration", type=float, default=5.0, help="seconds per scenario")
    ap.add_argument("--json-out", type=Path, help="also write the figures as JSON")
    args = ap.parse_args()

    with loadtest.local_service("--model", str(args.model), "--max-body-bytes", "1048576") as url:
        folder = read_model_folder(args.model)
        predictor = Predictor(folder)
        markers = folder.regions["markers"]
        direct = {"full": np.median(_direct_ms(predictor, None)), "markers": np.median(_direct_ms(predictor, markers))}
        rows = []
        for region, fmt, conc in [(None, "binary", 1), (None, "binary", 8), (None, "json", 1), (None, "json", 8),
                                  ("markers", "json", 1), ("markers", "binary", 1), ("markers", "json", 8)]:
            s = loadtest.run(url, concurrency=conc, duration_s=args.duration, fmt=fmt, region=region).summary()
            key = region or "full"
            rows.append({"region": key, "format": fmt, "concurrency": conc, **s,
                         "direct_ort_p50_ms": float(direct[key]), "ratio_p50": s["p50_ms"] / direct[key]})

    n = len(folder.nodes)
    print(f"model {folder.manifest['name']}: {n} nodes, rank {folder.manifest['pca']['rank']}; "
          f"service: 1 uvicorn process, onnxruntime 1 thread; clients on the same machine")
    print("| region | format | clients | p50 ms | p95 ms | p99 ms | max ms | req/s | errors | onnxruntime p50 ms | service/ort (p50) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['region']} | {r['format']} | {r['concurrency']} | {r['p50_ms']:.2f} | {r['p95_ms']:.2f} | "
              f"{r['p99_ms']:.2f} | {r['max_ms']:.2f} | {r['throughput_rps']:.0f} | {r['errors']} | "
              f"{r['direct_ort_p50_ms']:.3f} | {r['ratio_p50']:.1f} |")
    if args.json_out:
        args.json_out.write_text(json.dumps({"n_nodes": n, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
