"""How the service's default workers, lanes, threads and queue delay were chosen: each against its alternatives.

    python -m bench service-defaults [--duration 3] [--repeats 3] [--model M ...] [--publish]

For each model (models/default, whose basis stays in cache, and the paper-scale decoder, whose basis
is streamed from memory; built into runs/ when missing), each core set (the service pinned to one
core and to all usable cores, the clients placed as `bench service` places them) and each candidate
(workers, lanes a worker, onnxruntime threads, queue delay), starts the service with those flags and
loads it: a cached-basis model with 1 and 8 clients, a streamed one with 8 (full mesh, binary). The
defaults (service/cores.py's `Concurrency.for_model`) are one of the candidates. The candidates take
turns and each row is the median of `--repeats` runs. Prints, per core set and scenario, which
candidate served most and which had the lowest p99, and where the defaults rank; writes everything,
with the machine it ran on, to bench_service_defaults.json (docs/results/ with --publish).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from contracts.model import read_manifest
from service.cores import CACHED_BASIS_BYTES, MAX_DELAY_MS, Concurrency, basis_bytes, usable_cores
from service.settings import DEFAULT_MODEL
from studies import results

from . import paper_decoder
from .service import add_run_flags, core_sets, model_name, served, versions

FULL_1, FULL_8 = ("full binary 1", None, "binary", 1), ("full binary 8", None, "binary", 8)


def candidates(cores: int, *, cached: bool) -> list[Concurrency]:
    """The defaults for `cores` first, then the alternatives they were chosen over, each once.

    A streamed basis: one or two lanes, with and without the queue delay, at the defaults' workers and threads
    for all of each worker's cores. A cached one: a worker per core on one thread or two, and one worker of two
    lanes."""
    default = Concurrency.for_cores(cores, cached_basis=cached)
    if cached:
        alternatives = [Concurrency(cores, 1, 1), Concurrency(cores, 1, min(2, cores)), Concurrency(1, 2, 1)]
    else:
        threads = max(1, cores // default.workers)
        alternatives = [Concurrency(default.workers, lanes, threads, delay) for lanes in (1, 2)
                        for delay in (0.0, MAX_DELAY_MS)]
    return list(dict.fromkeys([default, *alternatives]))


def flags(c: Concurrency) -> list[str]:
    return ["--batching", "true", "--workers", str(c.workers), "--batch-lanes", str(c.lanes), "--threads",
            str(c.threads), "--batch-max-delay-ms", f"{c.max_delay_ms:g}"]


def label(c: Concurrency) -> str:
    return f"{c.workers} worker(s) x {c.lanes} lane(s) x {c.threads} thread(s), {c.max_delay_ms:g} ms delay"


def summarise(rows: list[dict]) -> list[dict]:
    """Per model, core count and scenario: the candidate that served most, the one with the lowest p99, and the
    defaults' rank (1 = best) and ratio to the best on each."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["n_nodes"], r["cores"], r["scenario"]), []).append(r)
    out = []
    for (n_nodes, cores, scenario), group in groups.items():
        default = next(r for r in group if r["default"])
        by_rps = sorted(group, key=lambda r: -r["throughput_rps"])
        by_p99 = sorted(group, key=lambda r: r["p99_ms"])
        out.append({"n_nodes": n_nodes, "cores": cores, "scenario": scenario, "candidates": len(group),
                    "most_rps": by_rps[0]["config"], "lowest_p99": by_p99[0]["config"],
                    "defaults": default["config"],
                    "defaults_rps_rank": by_rps.index(default) + 1, "defaults_p99_rank": by_p99.index(default) + 1,
                    "defaults_rps_vs_best": round(default["throughput_rps"] / by_rps[0]["throughput_rps"], 3),
                    "defaults_p99_vs_best": round(default["p99_ms"] / by_p99[0]["p99_ms"], 3)})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench service-defaults", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_flags(ap)
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.duration <= 0:
        ap.error("--repeats must be at least 1 and --duration positive")
    models = args.model or [DEFAULT_MODEL, paper_decoder.ensure()]
    for model in models:
        if not (Path(model) / "manifest.json").is_file():
            ap.error(f"--model: {model} is not a model folder (no manifest.json)")
    print(f"{usable_cores()} usable cores; load average {os.getloadavg()[0]:.2f}; {args.duration:g} s per run, "
          f"the median of {args.repeats} run(s) per row")
    data = {"duration_s": args.duration, "repeats": args.repeats, "load_at_start": os.getloadavg()[0],
            "versions": versions(), "rows": []}
    for model in models:
        n_nodes, size = read_manifest(model).mesh.n_nodes, basis_bytes(model)
        cached = size is not None and size <= CACHED_BASIS_BYTES
        print(f"\nmodel {model}: {n_nodes} nodes, basis {'cached' if cached else 'streamed'}\n| cores | candidate "
              "| scenario | p50 ms | p99 ms | req/s | errors | mean batch | |\n|---|---|---|---|---|---|---|---|---|")
        for cores in core_sets():
            default, *_ = options = candidates(len(cores), cached=cached)
            rows = served(model, cores, args.duration, large=not cached, repeats=args.repeats,
                          candidates=[(label(c), flags(c)) for c in options],
                          scenarios=[FULL_1, FULL_8] if cached else [FULL_8])
            data["rows"] += [{"model": model_name(model), "n_nodes": n_nodes, "cached_basis": cached,
                              "default": r["config"] == label(default), **r} for r in rows]
    data["load_at_end"] = os.getloadavg()[0]
    data["defaults_summary"] = summarise(data["rows"])
    print()
    for s in data["defaults_summary"]:
        print(f"{s['n_nodes']} nodes, {s['cores']} core(s), {s['scenario']}: defaults ({s['defaults']}) rank "
              f"{s['defaults_rps_rank']}/{s['candidates']} on req/s ({s['defaults_rps_vs_best']:.0%} of "
              f"{s['most_rps']}), {s['defaults_p99_rank']}/{s['candidates']} on p99 ({s['defaults_p99_vs_best']:.2f}x "
              f"{s['lowest_p99']})")
    print(f"\nwrote {results.write('bench_service_defaults', data, publish=args.publish)}")
    return 0
