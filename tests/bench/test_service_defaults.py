"""The defaults benchmark: its candidates, how it ranks the defaults among them, and the docs table."""

import pytest

from bench.service_defaults import candidates, flags, summarise
from service.cores import Concurrency
from studies.pages import defaults_table


@pytest.mark.parametrize("cores", [1, 2, 4, 8, 16])
@pytest.mark.parametrize("cached", [True, False])
def test_the_defaults_come_first_and_every_candidate_once(cores, cached):
    options = candidates(cores, cached=cached)
    assert options[0] == Concurrency.for_cores(cores, cached_basis=cached)
    assert len(options) == len(set(options)) >= 2


def test_a_streamed_basis_is_tried_with_one_and_two_lanes_with_and_without_the_delay():
    options = candidates(2, cached=False)
    assert {(c.lanes, c.max_delay_ms) for c in options} == {(1, 0.0), (1, 5.0), (2, 0.0), (2, 5.0)}
    assert all(c.workers == 1 and c.threads == 2 for c in options)


def test_flags_set_every_field_so_no_candidate_falls_back_to_the_defaults():
    from service.settings import Settings

    c = Concurrency(3, 2, 1, 0.0)
    args = flags(c)
    parsed = dict(zip(args[::2], args[1::2]))
    s = Settings(workers=parsed["--workers"], batch_lanes=parsed["--batch-lanes"], threads=parsed["--threads"],
                 batch_max_delay_ms=parsed["--batch-max-delay-ms"], batching=parsed["--batching"])
    assert (s.workers, s.batch_lanes, s.threads, s.batch_max_delay_ms, s.batching) == (3, 2, 1, 0.0, True)


def _rows():
    def row(config, rps, p99, default=False, scenario="full binary 8"):
        return {"n_nodes": 312_089, "cores": 2, "scenario": scenario, "config": config, "default": default,
                "throughput_rps": rps, "p50_ms": p99 / 2, "p99_ms": p99, "mean_batch": 4.0}

    return [row("a", 220.0, 42.0, default=True), row("b", 230.0, 70.0), row("c", 180.0, 55.0),
            row("a", 500.0, 3.0, default=True, scenario="full binary 1"),
            row("b", 400.0, 3.3, scenario="full binary 1")]


def test_the_defaults_are_ranked_against_the_best_of_each_figure():
    by = {s["scenario"]: s for s in summarise(_rows())}
    s = by["full binary 8"]
    assert (s["most_rps"], s["lowest_p99"], s["defaults"]) == ("b", "a", "a")
    assert (s["defaults_rps_rank"], s["defaults_p99_rank"], s["candidates"]) == (2, 1, 3)
    assert s["defaults_rps_vs_best"] == round(220 / 230, 3) and s["defaults_p99_vs_best"] == 1.0
    assert (by["full binary 1"]["defaults_rps_rank"], by["full binary 1"]["defaults_p99_rank"]) == (1, 1)


def test_the_docs_table_marks_the_defaults_and_their_rank(tmp_path):
    import json

    from studies.pages import result_block

    result = {"rows": _rows(), "defaults_summary": summarise(_rows())}
    table = defaults_table(result)
    assert table.count("(defaults)") == 2 and "| 2 of 3 | 1 of 3 | 0.96 | 1.00 |" in table
    (tmp_path / "bench_service_defaults.json").write_text(json.dumps(result))
    assert table in result_block("bench_service_defaults", tmp_path)
