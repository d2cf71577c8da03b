"""POST /predict once its body is parsed, in one direction: plan -> decode -> reply.

    plan    which nodes to decode, and for points where they lie (predict.plan); a lookup without points
    decode  one onnxruntime call per node set (predict.predict_batch), on one of three paths below
    reply   raw float32 or JSON in pieces (replies.reply)

Each step runs where it costs least. A cheap decode (`Pipeline.inline`) of a request that arrived alone (no
other /predict in the service) runs on the event loop: a thread hop would cost more than it, and under load the
batcher's lanes decode on other cores while the loop does HTTP. Everything else (locating points, decoding,
large JSON) runs off the event loop, in the batcher's lanes (batching.py) or, with batching off, in one thread
hop for the whole path, so the loop stays free for /healthz and other requests (onnxruntime and numpy release
the GIL; replies.py offers it back while writing JSON). Every path gives the same bytes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial
from typing import Callable

import numpy as np
from starlette.concurrency import run_in_threadpool
from starlette.responses import Response

from ..http import RequestProblem
from ..model import Predictor
from ..settings import Settings
from .batching import Batcher, QueueFull
from .decode import ALL_NODES, Query, plan, predict_batch
from .replies import reply, small_reply
from .schemas import PredictRequestBase


@dataclass(frozen=True)
class Pipeline:
    """What POST /predict needs once parsed, in one dependency (each dependency costs FastAPI some microseconds a
    request): the predictor, the batcher (None: batching is off) and the node sets decoded on the event loop."""

    predictor: Predictor
    model: str  # the model's name, in every JSON reply
    batcher: Batcher | None
    inline: frozenset[str]  # batching keys decoded on the event loop when nothing else is decoding (cheap_keys)

    @classmethod
    def start(cls, predictor: Predictor, *, model: str, settings: Settings,
              observe: Callable[[list[float], int], None]) -> Pipeline:
        """The pipeline with its batcher started (call on the event loop) and its cheap node sets measured now."""
        batcher = None
        if settings.batching:
            batcher = Batcher(partial(predict_batch, predictor), max_batch=settings.batch_max_size,
                              max_delay_s=settings.batch_max_delay_ms / 1e3, max_queue=settings.max_pending,
                              lanes=settings.batch_lanes, preferred=settings.batch_preferred_sizes, observe=observe)
            batcher.start()
        return cls(predictor, model, batcher, cheap_keys(predictor, settings.inline_max_ms))

    async def stop(self) -> None:
        if self.batcher is not None:
            await self.batcher.stop()

    async def respond(self, body: PredictRequestBase, fmt: str, *, alone: bool) -> Response:
        """The reply to a validated body in `fmt` ("json" or "binary"); `alone`: no other /predict in the service."""
        query = plan(self.predictor, body) if body.points is None else None  # without points, a lookup
        if query is not None and alone and query.key in self.inline and (self.batcher is None or self.batcher.idle):
            prediction = predict_batch(self.predictor, [query])[0]  # on the event loop
        elif self.batcher is None:
            return await run_in_threadpool(self.answer, body, query, fmt)
        else:
            prediction = await self.batched(query or await run_in_threadpool(plan, self.predictor, body))
        if small_reply(prediction, fmt):
            return reply(body, prediction, fmt=fmt, model=self.model)
        return await run_in_threadpool(reply, body, prediction, fmt=fmt, model=self.model)

    def answer(self, body: PredictRequestBase, query: Query | None, fmt: str) -> Response:
        """The whole path in the calling thread: plan (unless `query` is given), decode, reply."""
        prediction = predict_batch(self.predictor, [query or plan(self.predictor, body)])[0]
        return reply(body, prediction, fmt=fmt, model=self.model)

    async def batched(self, query: Query):
        """The query's prediction, decoded with whatever else waits for the same nodes; 503 when the queue is full."""
        try:
            return await self.batcher.submit(query)
        except QueueFull as exc:
            raise RequestProblem(503, field="request", type="overloaded", message=f"overloaded: {exc}",
                                 headers={"Retry-After": "1"}) from None


def decode_ms(predictor: Predictor, nodes: np.ndarray | None, *, repeats: int = 7) -> float:
    """The fastest of `repeats` single-guide decodes of `nodes` (all when None), ms: the decode's own cost. A median
    would count whatever else runs meanwhile, such as the other workers starting beside this one (why: CHANGELOG,
    "judged by a decode's fastest time at start")."""
    guide, times = np.array([[1.0, 0.0]]), []
    predictor.decode(guide, nodes)  # the first call of a shape allocates
    for _ in range(repeats):
        t0 = time.perf_counter()
        predictor.decode(guide, nodes)
        times.append((time.perf_counter() - t0) * 1e3)
    return min(times)


def cheap_keys(predictor: Predictor, budget_ms: float) -> frozenset[str]:
    """The batching keys (all nodes, each region) whose decode, measured now, takes at most `budget_ms`:
    the ones worth decoding on the event loop rather than through a thread."""
    if budget_ms <= 0:
        return frozenset()
    sets = {ALL_NODES: None, **{f"region:{name}": ids for name, ids in predictor.folder.regions.items()}}
    return frozenset(key for key, nodes in sets.items() if decode_ms(predictor, nodes) <= budget_ms)
