"""Dynamic batching, as Triton does it: requests that arrive together run as one call in one decode thread.

A collector task on the event loop takes the first waiting item, then everything else already
waiting (up to `max_batch`), and hands the batch to a single decode thread. While that thread
works, new requests wait in the queue and form the next batch, so under load batches grow by
themselves; a lone client is never held back. When the last batch had company, the collector also
waits up to `max_delay_s` after the first item's arrival for the batch to fill. The queue is
bounded: a full queue refuses new items (the route answers 503).
"""

from __future__ import annotations

import asyncio
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Generic, TypeVar

log = logging.getLogger(__name__)
T = TypeVar("T")
R = TypeVar("R")


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
                 max_queue: int, observe: Callable[[list[float], int], None] | None = None):
        self.run_batch, self.max_batch, self.max_delay_s = run_batch, max_batch, max_delay_s
        self.observe = observe or (lambda waits, size: None)
        self.queue: asyncio.Queue[_Waiting[T]] = asyncio.Queue(maxsize=max_queue)
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="decode")
        self._task: asyncio.Task | None = None
        self._last_size = 1

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._collect(), name="batch-collector")

    async def stop(self) -> None:
        """Stop collecting; items still waiting fail with QueueFull."""
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except asyncio.CancelledError:
                pass
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
        loop = asyncio.get_running_loop()
        while True:
            batch = [await self.queue.get()]
            self._take_waiting(batch)
            if len(batch) < self.max_batch and self.max_delay_s > 0 and self._last_size > 1:
                await self._wait_for_more(batch)
            batch = [w for w in batch if not w.future.done()]  # a client that went away was cancelled
            if not batch:
                continue
            now = time.perf_counter()
            self.observe([now - w.arrived for w in batch], len(batch))
            self._last_size = len(batch)
            try:
                results = await loop.run_in_executor(self._executor, self.run_batch, [w.item for w in batch])
            except Exception as exc:  # noqa: BLE001 - every waiting request gets the failure, not just the log
                log.exception("batch of %d failed", len(batch))
                results = [exc] * len(batch)
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
        deadline = batch[0].arrived + self.max_delay_s
        while len(batch) < self.max_batch and (left := deadline - time.perf_counter()) > 0:
            try:
                batch.append(await asyncio.wait_for(self.queue.get(), left))
            except TimeoutError:
                return
            self._take_waiting(batch)
