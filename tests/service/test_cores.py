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


@pytest.mark.parametrize("cores, expected", [(1, (1, 1, 1)), (2, (1, 2, 1)), (4, (1, 2, 2)), (8, (2, 2, 2)),
                                             (16, (4, 2, 2))])
def test_workers_lanes_and_threads_never_ask_for_more_cores_than_there_are(cores, expected):
    c = Concurrency.for_cores(cores)
    assert (c.workers, c.lanes, c.threads) == expected
    assert c.workers * c.lanes * c.threads <= cores


def test_the_settings_default_from_the_usable_cores_not_the_host(monkeypatch, tmp_path):
    """16 cores in the affinity but a 2-core quota: the service sizes itself for 2."""
    from service import cores
    from service.settings import Settings

    (tmp_path / "cpu.max").write_text("200000 100000\n")
    monkeypatch.setattr(cores, "CGROUP_CPU_MAX", tmp_path / "cpu.max")
    monkeypatch.setattr(cores.os, "sched_getaffinity", lambda pid: set(range(16)))
    s = Settings()
    assert (s.workers, s.batch_lanes, s.threads) == (1, 2, 1)
    assert Settings(workers=3, threads=2).workers == 3  # a flag still wins
