"""Dynamic batching, as Triton's dynamic batcher does it: requests that arrive together run as one call.

A collector task on the event loop waits for a free lane (one of `lanes` decode threads), takes
the first waiting item, then everything else already waiting (up to `max_batch`), and hands the
batch to that lane. While every lane works, new requests wait in the queue and form the next
batch, so under load batches grow by themselves; a lone client is never held back. Several lanes
decode at once (onnxruntime releases the GIL), so batching uses as many cores as running each
request in its own thread would.

The queue delay adapts: only when the last batch had company does the collector wait for more,
until the batch reaches the next preferred size (`preferred`, then `max_batch`) or the delay
runs out; the delay is `max_delay_s` capped at a quarter of the recent batch run time, so a cheap
decode never waits longer than it would take. It counts from when a lane is free, not from the
first item's arrival as Triton's does: under load that item waited through the last batch, so a
delay counted from it is over at once, and the clients whose replies were just sent never join;
the load then splits into cohorts that alternate in half-size batches (why: CHANGELOG, "A batch's
queue delay counts from when a lane is free"; the batch sizes it gives now are `mean_batch` in
docs/results/bench_service.json). The queue is bounded: a full queue refuses new items (the route
answers 503).
"""

from __future__ import annotations

import asyncio
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Generic, Sequence, TypeVar

log = logging.getLogger(__name__)
T = TypeVar("T")
R = TypeVar("R")
DELAY_FRACTION = 0.25  # of the recent batch run time: the most a batch waits to grow
RUN_TIME_WEIGHT = 0.2  # of the newest batch in the moving average of batch run times


class QueueFull(RuntimeError):
    """The batch queue holds `max_queue` items already."""


@dataclass
class _Waiting(Generic[T]):
    item: T
    future: asyncio.Future
    arrived: float = field(default_factory=time.perf_counter)


class Batcher(Generic[T, R]):
    """Run `run_batch(items) -> results` (one result per item, in order) over items submitted together.

    `observe(queue_seconds, batch_size)` is called on the event loop for each batch, with each item's
    time from submission to dispatch.
    """

    def __init__(self, run_batch: Callable[[list[T]], list[R]], *, max_batch: int, max_delay_s: float,
                 max_queue: int, lanes: int = 1, preferred: Sequence[int] = (),
                 observe: Callable[[list[float], int], None] | None = None):
        self.run_batch, self.max_batch, self.max_delay_s, self.lanes = run_batch, max_batch, max_delay_s, lanes
        self.sizes = sorted({s for s in preferred if s < max_batch} | {max_batch})  # worth waiting for
        self.observe = observe or (lambda waits, size: None)
        self.queue: asyncio.Queue[_Waiting[T]] = asyncio.Queue(maxsize=max_queue)
        self._executor = ThreadPoolExecutor(max_workers=lanes, thread_name_prefix="decode")
        self._task: asyncio.Task | None = None
        self._free: asyncio.Semaphore | None = None
        self._running: set[asyncio.Task] = set()
        self._last_size = 1
        self._run_s = 0.0  # moving average of a batch's run time

    @property
    def idle(self) -> bool:
        """Nothing waits and no batch runs: a request sent now would run alone at once."""
        return not self._running and self.queue.empty()

    def start(self) -> None:
        self._free = asyncio.Semaphore(self.lanes)
        self._task = asyncio.get_running_loop().create_task(self._collect(), name="batch-collector")

    async def stop(self) -> None:
        """Stop collecting and let running batches finish; items still waiting fail with QueueFull."""
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except asyncio.CancelledError:
                pass
        if self._running:
            await asyncio.wait(set(self._running))
        while not self.queue.empty():
            waiting = self.queue.get_nowait()
            if not waiting.future.done():
                waiting.future.set_exception(QueueFull("the service is shutting down"))
        self._executor.shutdown(wait=True)

    async def submit(self, item: T) -> R:
        """The item's result, computed in a batch with whatever else is waiting; QueueFull if the queue is full."""
        waiting = _Waiting(item, asyncio.get_running_loop().create_future())
        try:
            self.queue.put_nowait(waiting)
        except asyncio.QueueFull:
            raise QueueFull(f"{self.queue.maxsize} requests are waiting already") from None
        return await waiting.future

    async def _collect(self) -> None:
        while True:
            await self._free.acquire()  # a lane is free
            batch = [await self.queue.get()]
            self._take_waiting(batch)
            if self._last_size > 1 and len(batch) < self.max_batch:
                await self._wait_for_more(batch)
            batch = [w for w in batch if not w.future.done()]  # a client that went away was cancelled
            if not batch:
                self._free.release()
                continue
            self.observe([time.perf_counter() - w.arrived for w in batch], len(batch))
            self._last_size = len(batch)
            task = asyncio.get_running_loop().create_task(self._run(batch))
            self._running.add(task)
            task.add_done_callback(self._running.discard)

    async def _run(self, batch: list[_Waiting[T]]) -> None:
        t0 = time.perf_counter()
        try:
            results = await asyncio.get_running_loop().run_in_executor(
                self._executor, self.run_batch, [w.item for w in batch])
        except Exception as exc:  # noqa: BLE001 - every waiting request gets the failure, not just the log
            log.exception("batch of %d failed", len(batch))
            results = [exc] * len(batch)
        finally:
            self._run_s += RUN_TIME_WEIGHT * (time.perf_counter() - t0 - self._run_s)
            self._free.release()
        for waiting, result in zip(batch, results):
            if waiting.future.done():
                continue
            if isinstance(result, Exception):
                waiting.future.set_exception(result)
            else:
                waiting.future.set_result(result)

    def _take_waiting(self, batch: list[_Waiting[T]]) -> None:
        while len(batch) < self.max_batch and not self.queue.empty():
            batch.append(self.queue.get_nowait())

    async def _wait_for_more(self, batch: list[_Waiting[T]]) -> None:
        """Wait for the batch to reach the next size worth having,
        at most the adaptive delay from now (a lane is free)."""
        target = next(s for s in self.sizes if s >= len(batch))
        deadline = time.perf_counter() + min(self.max_delay_s, DELAY_FRACTION * self._run_s)
        while len(batch) < target and (left := deadline - time.perf_counter()) > 0:
            try:
                batch.append(await asyncio.wait_for(self.queue.get(), left))
            except TimeoutError:
                return
            self._take_waiting(batch)
