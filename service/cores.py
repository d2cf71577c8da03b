"""The cores this process may use, and the service's process and thread counts derived from them.

`usable_cores` reads the CPU affinity (taskset, a container's cpuset) and the cgroup v2 CPU quota
(`cpu.max`, what `docker --cpus` sets), not os.cpu_count(), which counts the host's cores. This
module is its one owner: studies.results imports it from here.

The defaults (`Concurrency.for_cores`) were chosen by measurement on a 2-core machine pinned to 1
and 2 cores; above 2 cores they are a rule, not a measurement. Each default is served beside the
alternatives it was chosen over in docs/results/bench_service_defaults.json (`python -m bench
service-defaults`); the CHANGELOG says what each choice gained when it was made. They depend on the
model's basis (`Concurrency.for_model`):
* a large basis (over `CACHED_BASIS_BYTES`, streamed from memory on every decode): one worker
  process below 8 cores, since a single process batches more (a decode reads the whole basis once
  per call, whatever the batch size). On 2 to 7 cores its one batch executor (lane) has onnxruntime
  threads for every core and sends a batch as soon as it is free, so the clients fall into two
  cohorts, one decoding while the other's replies are written: the throughput of two lanes with a
  queue delay, at a lower p99 (see for_cores). On 1 core batches wait up to MAX_DELAY_MS to grow.
* a basis that stays in cache: a decode costs little per request whatever the batching, and one
  event loop's HTTP is the bottleneck, so one worker per core below 8 cores, each with one lane.
  Each worker's session has two onnxruntime threads (from 2 cores on), so a request that comes
  alone decodes on two cores.
* from 8 cores, one worker per 4 cores for either, so HTTP and serialisation scale, each with two lanes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from contracts.model import read_manifest

CGROUP_CPU_MAX = Path("/sys/fs/cgroup/cpu.max")
# a basis (float32, 3 n_nodes x (rank + 1)) up to this size is decoded from cache; above it, from memory. 32 MB: the
# L3 of a current server core complex; models/default's is 12 MB, the paper-scale decoder's 154 MB
CACHED_BASIS_BYTES = 32 << 20


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


# the most a batch waits to grow (service/predict/batching.py), ms, unless a streamed basis runs on 2 to 7
# cores (for_cores)
MAX_DELAY_MS = 5.0


@dataclass(frozen=True)
class Concurrency:
    """Worker processes, batch executors per worker, onnxruntime intra-op threads per session, and the most a
    batch waits to grow (ms)."""

    workers: int
    lanes: int
    threads: int
    max_delay_ms: float = MAX_DELAY_MS

    @classmethod
    def for_cores(cls, cores: int, *, cached_basis: bool = False) -> Concurrency:
        if cores >= 8:
            workers = cores // 4
        else:
            workers = cores if cached_basis else 1
        per_worker = max(1, cores // workers)
        if not cached_basis and 2 <= cores < 8:
            # One lane on every core, batches sent as soon as the lane is free: 8 clients then split into two cohorts
            # of 4, one decoding while the other's replies go out, as regular as a clock; with two lanes and a delay,
            # stragglers wait a second cycle and the p99 is higher at the same throughput. On 1 core the delay pays in
            # throughput instead. why: docs/results/bench_service_defaults.json (each against its alternative)
            return cls(workers=1, lanes=1, threads=cores, max_delay_ms=0.0)
        lanes = min(2, per_worker)
        # A streamed basis gives each lane all the worker's cores: under load its batches are large and one lane often
        # decodes alone while the other waits for company, and a lone batch's Gemm then runs on every core. A cached
        # one gives each lane its share of the worker's cores, but at least two where there are two: a lone request's
        # decode then splits over two cores, and under load the extra threads sleep rather than spin
        # (contracts.model.onnx_session). Under load they cost some throughput, but a lone request is the common case
        # (a guide polling its answer each frame), so two threads. why: docs/results/bench_service_defaults.json
        # (8 clients on 2 cores against one thread) and the CHANGELOG (a lone request on one thread and on two)
        threads = max(per_worker // lanes, min(2, cores)) if cached_basis else per_worker
        return cls(workers=workers, lanes=lanes, threads=threads)

    @classmethod
    def for_model(cls, cores: int, basis_bytes: int | None) -> Concurrency:
        """The defaults for a model whose basis takes `basis_bytes` (None: unknown, taken as large)."""
        return cls.for_cores(cores, cached_basis=basis_bytes is not None and basis_bytes <= CACHED_BASIS_BYTES)


def basis_bytes(model: Path) -> int | None:
    """The float32 basis of a model folder from its manifest (3 n_nodes x (rank + 1) x 4 bytes); None if unreadable."""
    try:
        manifest = read_manifest(model)
    except (OSError, ValueError):  # missing, unreadable or not a manifest (ModelError)
        return None
    return 3 * manifest.mesh.n_nodes * (manifest.pca.rank + 1) * 4


def defaults(model: Path | None = None) -> Concurrency:
    """The service's defaults for the cores this process may use and the model it serves."""
    return Concurrency.for_model(usable_cores(), basis_bytes(model) if model is not None else None)
