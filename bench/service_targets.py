"""Issue #35's targets, where a large request's CPU goes, and the README's speed rows, from bench/service.py's
measurements."""

from __future__ import annotations


def _models(data: dict) -> tuple[dict, dict]:
    entries = sorted(data["models"].values(), key=lambda m: m["n_nodes"])
    return entries[0], entries[-1]


def _row(model: dict, cores: int, config: str, scenario: str) -> dict | None:
    return next((r for r in model["rows"] if r["cores"] == cores and r["config"] == config
                 and r["scenario"] == scenario), None)


def _best_off(model: dict, cores: int, scenario: str) -> dict | None:
    offs = [r for r in model["rows"] if r["cores"] == cores and r["config"].startswith("off")
            and r["scenario"] == scenario]
    return max(offs, key=lambda r: r["throughput_rps"], default=None)


def _target(target: str, value, met: bool) -> dict:
    return {"target": target, "value": value, "met": bool(met)}


def targets(data: dict) -> list[dict]:
    small, large = _models(data)
    n = max(r["cores"] for r in large["rows"])
    out = []
    on, off = _row(large, n, "on", "full binary 8"), _best_off(large, n, "full binary 8")
    if on and off:
        ratio = on["throughput_rps"] / off["throughput_rps"]
        out.append(_target(f"{large['n_nodes']} nodes, 8 clients, full binary, {n} cores: batching on >= 1.6x the best "
                           f"batching-off config ({off['config']})", round(ratio, 2), ratio >= 1.6))
        out.append(_target(f"{large['n_nodes']} nodes, 8 clients, full binary, {n} cores, batching on: p99 <= 40 ms",
                           round(on["p99_ms"], 1), on["p99_ms"] <= 40))
    for p in large["in_process"]:
        row = _row(large, p["cores"], "on", "full binary 8")
        if row:
            share = row["throughput_rps"] / p["decode_capacity_rps"]
            out.append(_target(f"{large['n_nodes']} nodes, 8 clients, {p['cores']} core(s): served >= 50% of the "
                               "in-process decode capacity", round(share, 2), share >= 0.5))
        per_request = 1e3 * p["cores"] / p["decode_capacity_rps"]  # core-ms a request at the best capacity
        outside = p["reference_positions_ms"] + p["binary_reply_ms"]
        out.append(_target(f"{large['n_nodes']} nodes, {p['cores']} core(s): work outside onnxruntime (reference "
                           f"positions + binary reply, ms) below the batched decode per request ({per_request:.2f} "
                           "core-ms)",
                           round(outside, 3), outside < per_request))
    on1, off1 = _row(small, n, "on", "full binary 1"), _best_off(small, n, "full binary 1")
    if on1 and off1:
        out.append(_target(f"{small['n_nodes']} nodes, 1 client, full binary, {n} cores: p99 with batching no worse "
                           f"than without ({off1['p99_ms']:.2f} ms)", round(on1["p99_ms"], 2),
                           on1["p99_ms"] <= off1["p99_ms"]))
        lone = next((p for p in small["in_process"] if p["cores"] == n and "decode_lone_p99_ms" in p), None)
        floor = f" (the decode alone, in process, 1 ms apart: p99 {lone['decode_lone_p99_ms']:.2f} ms)" if lone else ""
        out.append(_target(f"{small['n_nodes']} nodes, 1 client, full binary, defaults, {n} cores: p99 <= 1.5 ms"
                           f"{floor}", round(on1["p99_ms"], 2), on1["p99_ms"] <= 1.5))
    markers = _row(small, n, "on", "markers binary 1")
    if markers:
        out.append(_target(f"markers, 1 client, defaults, {n} cores: p99 <= 1 ms", round(markers["p99_ms"], 2),
                           markers["p99_ms"] <= 1.0))
    json_rows = [r for r in large["rows"] if "healthz_p99_ms" in r]
    if json_rows:
        worst = max(r["healthz_p99_ms"] for r in json_rows)
        out.append(_target(f"/healthz p99 <= 50 ms while {large['n_nodes']}-node JSON replies are in flight "
                           "(worst configuration)", round(worst, 1), worst <= 50))
    out.append(_target(">= 8 cores: batching on >= 1.5x the best batching-off config", "not measured (no such machine)",
                       False))
    return out


def cpu_rows(data: dict) -> list[dict]:
    """Per core set, where the large model's batched requests (8 clients, full binary) spend CPU, in core-ms per
    request: the decode alone (in process), the service's processes and the clients (bench/service.py's CPU
    fields). `bound_rps` is what the service would serve if every core it has (and the clients have, where they
    share them) were busy at that cost; `busy` the served share of that bound. So served / capacity =
    decode / (service + clients on the same cores) x busy: the first factor is the work besides the decode, the
    second the time the cores wait."""
    _, large = _models(data)
    out = []
    for p in large["in_process"]:
        row = _row(large, p["cores"], "on", "full binary 8")
        if not row or row.get("service_user_ms") is None:
            continue
        service = row["service_user_ms"] + row["service_sys_ms"]
        clients = row["client_user_ms"] + row["client_sys_ms"]
        on_cores = service + (clients if row.get("clients_share_cores") else 0.0)
        bound = 1e3 * p["cores"] / on_cores
        out.append({"cores": p["cores"], "decode_ms": round(1e3 * p["cores"] / p["decode_capacity_rps"], 2),
                    "service_user_ms": round(row["service_user_ms"], 2),
                    "service_sys_ms": round(row["service_sys_ms"], 2),
                    "client_ms": round(clients, 2), "clients_share_cores": bool(row.get("clients_share_cores")),
                    "bound_rps": round(bound, 1), "served_rps": round(row["throughput_rps"], 1),
                    "busy": round(row["throughput_rps"] / bound, 2),
                    "served_share": round(row["throughput_rps"] / p["decode_capacity_rps"], 2)})
    return out


def readme_rows(data: dict) -> list[dict]:
    small, large = _models(data)
    n = max(r["cores"] for r in large["rows"])
    picks = [(small, "on", "markers binary 1",
              f"default model ({small['n_nodes']:,} nodes), markers, binary, 1 client"),
             (small, "on", "full binary 1", "default model, full mesh, binary, 1 client"),
             (small, "on", "full binary 8", "default model, full mesh, binary, 8 clients"),
             (large, "on", "full binary 8", f"{large['n_nodes']:,} nodes, full mesh, binary, 8 clients, batching on"),
             (large, None, "full binary 8", f"{large['n_nodes']:,} nodes, full mesh, binary, 8 clients, batching off"),
             (large, "on", "full json 8", f"{large['n_nodes']:,} nodes, full mesh, JSON, 8 clients, batching on")]
    rows = []
    for model, config, scenario, what in picks:
        r = _row(model, n, config, scenario) if config else _best_off(model, n, scenario)
        if r:
            rows.append({"what": f"{what} ({n} cores)", "p50_ms": round(r["p50_ms"], 2),
                         "p99_ms": round(r["p99_ms"], 2), "req_s": round(r["throughput_rps"], 1)})
    return rows
