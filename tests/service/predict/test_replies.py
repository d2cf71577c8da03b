"""Reply bodies: JSON in pieces is orjson's own text, and writing a large one leaves the event loop free."""

import asyncio
import threading

import httpx
import numpy as np
import orjson

from service.predict.replies import ChunkedResponse, array_chunks, json_chunks


def test_json_in_pieces_is_the_same_text_as_in_one_call():
    rng = np.random.default_rng(0)
    arrays = {"positions": rng.normal(size=(20_001, 3)).astype(np.float32),
              "node_ids": np.arange(20_001, dtype=np.int64)}
    scalars = {"model": "m", "displacement_mm": 5.0, "region": None, "count": 20_001}
    pieces = json_chunks(scalars, arrays)
    whole = orjson.dumps({**scalars, **arrays}, option=orjson.OPT_SERIALIZE_NUMPY)
    assert len(pieces) > 5 and b"".join(pieces) == whole
    assert b"".join(array_chunks(arrays["positions"][:3])) == orjson.dumps(
        arrays["positions"][:3], option=orjson.OPT_SERIALIZE_NUMPY)


def test_healthz_answers_while_a_large_json_reply_is_written():
    """A 300k-row JSON reply (about 20 MB, serialised in a worker thread in pieces) is in flight while
    /healthz is polled: polls complete before it does. Serialised in one orjson call on the loop, none could."""
    from fastapi import FastAPI
    from starlette.concurrency import run_in_threadpool

    positions = np.random.default_rng(1).normal(size=(300_000, 3)).astype(np.float32)
    app, started = FastAPI(), threading.Event()

    def build():
        started.set()
        return ChunkedResponse(json_chunks({"count": len(positions)}, {"positions": positions}))

    @app.get("/big")
    async def big():
        return await run_in_threadpool(build)

    @app.get("/healthz")
    async def healthz():
        return {"status": "ok"}

    async def scenario():
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://s") as client:
            reply = asyncio.create_task(client.get("/big"))
            await asyncio.to_thread(started.wait, 5)
            polls = 0
            while not reply.done():
                assert (await client.get("/healthz")).status_code == 200
                polls += not reply.done()
                await asyncio.sleep(0.001)  # a poll every millisecond; lets the reply's task run too
            return polls, await reply

    polls, reply = asyncio.run(scenario())
    assert polls >= 3
    got = orjson.loads(reply.content)
    assert int(reply.headers["content-length"]) == len(reply.content)
    np.testing.assert_array_equal(np.asarray(got["positions"], dtype=np.float32), positions)


def test_at_most_two_large_arrays_are_serialised_at_once(monkeypatch):
    """Eight large JSON replies at once: each waits for one of the two writers, so the event loop competes for the
    GIL with two threads, not eight; every reply is still orjson's own text."""
    import threading
    import time

    from service.predict import replies

    lock, active, peak, real = threading.Lock(), [0], [0], replies.orjson.dumps

    class Counting:
        OPT_SERIALIZE_NUMPY = orjson.OPT_SERIALIZE_NUMPY

        @staticmethod
        def dumps(value, option=None):
            with lock:
                active[0] += 1
                peak[0] = max(peak[0], active[0])
            time.sleep(0.005)
            with lock:
                active[0] -= 1
            return real(value, option=option)

    monkeypatch.setattr(replies, "orjson", Counting)
    array = np.arange(3 * replies.CHUNK_ROWS * 3, dtype=np.float32).reshape(-1, 3)
    out = [None] * 8

    def write(i):
        out[i] = b"".join(array_chunks(array))

    threads = [threading.Thread(target=write, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert peak[0] == 2
    assert all(o == real(array, option=orjson.OPT_SERIALIZE_NUMPY) for o in out)
