"""The cores this process may use, and the service's process and thread counts derived from them.

`usable_cores` reads the CPU affinity (taskset, a container's cpuset) and the cgroup v2 CPU quota
(`cpu.max`, what `docker --cpus` sets), not os.cpu_count(), which counts the host's cores. This
module is its one owner: studies.results imports it from here.

The defaults (`Concurrency.for_cores`) were chosen by measurement on a 2-core machine pinned to 1
and 2 cores (bench/service.py, docs/results/bench_service.json); above 2 cores they are a rule,
not a measurement:
* one worker process below 8 cores: a single process batches more (batches are what make a
  paper-scale decode cheap: it reads the whole basis once per call, whatever the batch size);
  from 8 cores one worker per 4 cores, so HTTP and serialisation (one event loop a process) scale.
* two batch executors (lanes) from 2 cores on, so one batch decodes while the last one's replies are
  written; onnxruntime intra-op threads share the rest of a worker's cores between its lanes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

CGROUP_CPU_MAX = Path("/sys/fs/cgroup/cpu.max")


def usable_cores(*, affinity: set[int] | None = None, cpu_max: Path | None = None) -> int:
    """Cores this process may run on: its CPU affinity, capped by a cgroup v2 CPU quota (rounded up).

    `cpu.max` holds "QUOTA PERIOD" in microseconds, or "max PERIOD" for no quota.
    """
    if affinity is None:
        affinity = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set(range(os.cpu_count() or 1))
    cores = max(1, len(affinity))
    try:
        quota, period = Path(CGROUP_CPU_MAX if cpu_max is None else cpu_max).read_text().split()
        if quota != "max":
            cores = max(1, min(cores, -(-int(quota) // int(period))))
    except (OSError, ValueError):
        pass
    return cores


@dataclass(frozen=True)
class Concurrency:
    """Worker processes, batch executors per worker and onnxruntime intra-op threads per session."""

    workers: int
    lanes: int
    threads: int

    @classmethod
    def for_cores(cls, cores: int) -> Concurrency:
        workers = 1 if cores < 8 else cores // 4
        per_worker = max(1, cores // workers)
        lanes = min(2, per_worker)
        return cls(workers=workers, lanes=lanes, threads=max(1, per_worker // lanes))


def defaults() -> Concurrency:
    """The service's defaults for the cores this process may use."""
    return Concurrency.for_cores(usable_cores())
