"""Core counts: the affinity and the cgroup quota bound the cores, and the service's defaults follow them."""

import pytest

from service.cores import Concurrency, usable_cores


def test_the_affinity_counts_when_there_is_no_quota(tmp_path):
    (tmp_path / "cpu.max").write_text("max 100000\n")
    assert usable_cores(affinity={0, 3, 5}, cpu_max=tmp_path / "cpu.max") == 3


@pytest.mark.parametrize("quota, expected", [("150000 100000", 2), ("100000 100000", 1), ("50000 100000", 1),
                                             ("800000 100000", 4)])
def test_a_cgroup_quota_caps_the_affinity_rounded_up(tmp_path, quota, expected):
    (tmp_path / "cpu.max").write_text(quota + "\n")
    assert usable_cores(affinity=set(range(4)), cpu_max=tmp_path / "cpu.max") == expected


def test_no_cgroup_file_leaves_the_affinity(tmp_path):
    assert usable_cores(affinity={1}, cpu_max=tmp_path / "missing") == 1


@pytest.mark.parametrize("cores, expected", [(1, (1, 1, 1, 5.0)), (2, (1, 1, 2, 0.0)), (4, (1, 1, 4, 0.0)),
                                             (8, (2, 2, 4, 5.0)), (16, (4, 2, 4, 5.0))])
def test_a_streamed_basis_gets_one_batching_worker_whose_lanes_may_each_use_all_its_cores(cores, expected):
    """Below 8 cores one worker, its one lane on every core, sending batches without a queue delay from 2 cores on
    (the clients form cohorts); on 1 core a batch waits to grow; from 8 cores a worker per 4 cores, two lanes each."""
    c = Concurrency.for_cores(cores)
    assert (c.workers, c.lanes, c.threads, c.max_delay_ms) == expected
    assert c.workers * c.threads <= cores  # each lane's threads fit the cores; two lanes share them


@pytest.mark.parametrize("cores, expected", [(1, (1, 1, 1)), (2, (2, 1, 2)), (4, (4, 1, 2)), (8, (2, 2, 2)),
                                             (16, (4, 2, 2))])
def test_a_model_decoded_from_cache_gets_a_worker_per_core_below_8(cores, expected):
    """A basis that stays in cache (models/default's 12 MB) makes HTTP the bottleneck: a worker per core, each
    decoding a lone request on two threads where there are two cores; a large one (the paper-scale decoder's 154 MB)
    keeps one batching worker; an unknown size counts as large."""
    from service.cores import CACHED_BASIS_BYTES

    small, large = Concurrency.for_model(cores, 12 << 20), Concurrency.for_model(cores, 154 << 20)
    assert (small.workers, small.lanes, small.threads) == expected
    assert large == Concurrency.for_cores(cores) == Concurrency.for_model(cores, None)
    assert Concurrency.for_model(cores, CACHED_BASIS_BYTES + 1) == large
    assert small.workers * small.lanes <= cores  # a lane per core; a lone request's threads may take a second one


def test_the_settings_size_the_service_for_the_model_it_serves(monkeypatch, tmp_path):
    import json

    from service import cores
    from service.settings import DEFAULT_MODEL, Settings

    monkeypatch.setattr(cores.os, "sched_getaffinity", lambda pid: {0, 1})
    monkeypatch.setattr(cores, "CGROUP_CPU_MAX", tmp_path / "missing")
    manifest = json.loads((DEFAULT_MODEL / "manifest.json").read_text())
    assert cores.basis_bytes(DEFAULT_MODEL) == 3 * manifest["mesh"]["n_nodes"] * (manifest["pca"]["rank"] + 1) * 4
    assert (Settings().workers, Settings().batch_lanes) == (2, 1)  # models/default: 12 MB
    big = tmp_path / "big"
    big.mkdir()
    manifest["mesh"]["n_nodes"] = 312_089
    (big / "manifest.json").write_text(json.dumps(manifest))
    s = Settings(model=big)
    assert (s.workers, s.batch_lanes, s.threads, s.batch_max_delay_ms) == (1, 1, 2, 0.0)
    assert Settings(model=big, batch_max_delay_ms=2).batch_max_delay_ms == 2  # a flag still wins
    assert Settings().batch_max_delay_ms == 5.0  # models/default


def test_the_settings_default_from_the_usable_cores_not_the_host(monkeypatch, tmp_path):
    """16 cores in the affinity but a 2-core quota: the service sizes itself for 2."""
    from service import cores
    from service.settings import Settings

    (tmp_path / "cpu.max").write_text("200000 100000\n")
    monkeypatch.setattr(cores, "CGROUP_CPU_MAX", tmp_path / "cpu.max")
    monkeypatch.setattr(cores.os, "sched_getaffinity", lambda pid: set(range(16)))
    s = Settings()
    assert (s.workers, s.batch_lanes, s.threads) == (2, 1, 2)  # models/default decodes from cache: a worker per core
    assert (Settings(workers=3, threads=1).workers, Settings(workers=3, threads=1).threads) == (3, 1)  # flags still win
