"""The service benchmark's targets and README rows, read from its measurements."""

from bench.service_targets import readme_rows, targets


def _row(cores, config, scenario, rps, p99, **extra):
    return {"cores": cores, "config": config, "scenario": scenario, "throughput_rps": rps, "p50_ms": p99 / 2,
            "p99_ms": p99, **extra}


def _data():
    small = {"n_nodes": 10_123, "in_process": [{"cores": 2, "decode_lone_p99_ms": 0.94}], "rows": [
        _row(2, "off", "full binary 1", 600, 1.2), _row(2, "on", "full binary 1", 700, 1.1),
        _row(2, "on", "markers binary 1", 1500, 0.8), _row(2, "on", "full binary 8", 2000, 5.0)]}
    large = {"n_nodes": 312_089, "in_process": [
        {"cores": 2, "defaults": {"workers": 1, "lanes": 2, "threads": 1}, "decode_capacity_rps": 400.0,
         "reference_positions_ms": 0.08, "binary_reply_ms": 0.01}], "rows": [
        _row(2, "off", "full binary 8", 100, 60), _row(2, "off, 2 workers", "full binary 8", 150, 50),
        _row(2, "on", "full binary 8", 250, 35), _row(2, "on", "full json 8", 20, 400, healthz_p99_ms=12.0)]}
    return {"models": {"a": small, "b": large}}


def test_batching_is_judged_against_the_best_unbatched_config():
    t = {x["target"]: x for x in targets(_data())}
    ratio = next(v for k, v in t.items() if "1.6x" in k)
    assert ratio["value"] == round(250 / 150, 2) and ratio["met"]
    share = next(v for k, v in t.items() if "decode capacity" in k)
    assert share["value"] == 0.62 and share["met"]
    outside = next(v for k, v in t.items() if "outside onnxruntime" in k)
    assert "(5.00 core-ms)" in next(k for k in t if "outside onnxruntime" in k)  # 2 cores at 400 req/s
    assert outside["value"] == 0.09 and outside["met"]


def test_every_target_says_whether_it_is_met_and_the_unmeasured_one_is_not():
    t = targets(_data())
    assert all(set(x) == {"target", "value", "met"} and isinstance(x["met"], bool) for x in t)
    assert not next(x for x in t if x["target"].startswith(">= 8 cores"))["met"]
    assert next(x for x in t if "/healthz" in x["target"])["met"]
    lone = next(x for x in t if "p99 <= 1.5 ms" in x["target"])
    assert "the decode alone, in process, 1 ms apart: p99 0.94 ms" in lone["target"] and lone["met"]  # 1.1 ms


def test_readme_rows_have_the_fields_the_readme_table_reads():
    rows = readme_rows(_data())
    assert len(rows) == 6
    assert all(set(r) == {"what", "p50_ms", "p99_ms", "req_s"} for r in rows)
    off = next(r for r in rows if "batching off" in r["what"])
    assert off["req_s"] == 150  # the best unbatched configuration


def test_a_repeated_row_is_the_median_of_its_runs():
    from bench.service import median_row

    runs = [_row(2, "on", "full binary 8", rps, p99, requests=100, errors=e, mean_batch=b)
            for rps, p99, e, b in [(200.0, 50.0, 0, 7.0), (260.0, 40.0, 1, 6.0), (240.0, 45.0, 0, None)]]
    row = median_row(runs)
    assert (row["throughput_rps"], row["p99_ms"], row["p50_ms"]) == (240.0, 45.0, 22.5)
    assert (row["requests"], row["errors"], row["repeats"], row["mean_batch"]) == (300, 1, 3, 6.5)
    assert row["throughput_runs_rps"] == [200.0, 260.0, 240.0] and row["config"] == "on"


def test_the_cpu_rows_account_for_the_served_share_of_the_capacity():
    from bench.service_targets import cpu_rows

    data = _data()
    row = next(r for r in data["models"]["b"]["rows"] if r["config"] == "on" and r["scenario"] == "full binary 8")
    row.update(service_user_ms=3.0, service_sys_ms=1.0, client_user_ms=0.25, client_sys_ms=0.75,
               clients_share_cores=True)
    (c,) = cpu_rows(data)
    # 2 cores, capacity 400 req/s: the decode alone takes 5 core-ms a request; service + clients 5 on those cores
    assert (c["decode_ms"], c["client_ms"], c["bound_rps"], c["busy"]) == (5.0, 1.0, 400.0, 0.62)
    assert c["served_share"] == round(c["decode_ms"] / (4.0 + 1.0) * 250 / 400, 2)
    row["clients_share_cores"] = False  # clients on other cores cost the service's cores nothing
    assert cpu_rows(data)[0]["bound_rps"] == 500.0
    del row["service_user_ms"]
    assert cpu_rows(data) == []  # a result measured without the CPU fields
