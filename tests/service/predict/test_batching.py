"""Dynamic batching: requests decoded together get exactly their own answers; the queue is bounded."""

import asyncio
import re
import threading

import httpx
import numpy as np
import pytest

from service.predict.batching import Batcher, QueueFull
from service.predict.decode import plan, predict, predict_batch


def test_a_batch_of_different_requests_gives_each_its_own_answer(predictor, request_model):
    """Full-mesh, region and point requests with different guides, decoded in one batch, equal their solo decodes."""
    nodes = predictor.folder.nodes
    inside = nodes[predictor.folder.tets[:6, :4]].mean(axis=1).tolist()  # tet centroids
    requests = [request_model(displacement_mm=d, angle_deg=a, **extra) for d, a, extra in [
        (5.0, 2.0, {}), (9.5, -7.0, {"region": "markers"}), (1.0, 3.0, {}), (5.0, 2.0, {"region": "prostate"}),
        (7.25, -1.5, {"points": inside}), (3.0, 9.0, {"region": "markers"}), (10.0, -10.0, {}),
        (2.0, 0.5, {"points": inside[:3]})]]
    batched = predict_batch(predictor, [plan(predictor, r) for r in requests])
    for request, got in zip(requests, batched):
        solo = predict(predictor, request)
        assert got.region == solo.region
        np.testing.assert_array_equal(got.positions, solo.positions)  # bit for bit
        for name in ("displacements", "node_ids"):
            a, b = getattr(got, name), getattr(solo, name)
            assert (a is None) == (b is None) and (a is None or np.array_equal(a, b))
    # the full-mesh answers differ from one another by millimetres, so a swap would not pass the checks above
    assert np.abs(batched[0].positions - batched[2].positions).max() > 1.0


def test_requests_that_wait_together_run_as_one_batch_in_order():
    calls, entered, release = [], threading.Event(), threading.Event()

    def run_batch(items):
        calls.append(list(items))
        entered.set()
        release.wait(5)
        return [item * 10 for item in items]

    async def scenario():
        batcher = Batcher(run_batch, max_batch=4, max_delay_s=0.0, max_queue=16)
        batcher.start()
        first = asyncio.create_task(batcher.submit(0))
        await asyncio.to_thread(entered.wait, 5)  # 0 is in the decode thread; the rest queue behind it
        rest = [asyncio.create_task(batcher.submit(i)) for i in range(1, 7)]
        await asyncio.sleep(0)
        release.set()
        results = await asyncio.gather(first, *rest)
        await batcher.stop()
        return results

    assert asyncio.run(scenario()) == [0, 10, 20, 30, 40, 50, 60]
    assert calls == [[0], [1, 2, 3, 4], [5, 6]]  # at most max_batch each, in arrival order


def test_a_lone_request_does_not_wait_for_the_delay():
    """After a batch of one, the next request goes at once even with a 60 s delay configured."""
    async def scenario():
        batcher = Batcher(lambda items: items, max_batch=8, max_delay_s=60.0, max_queue=8)
        batcher.start()
        results = [await asyncio.wait_for(batcher.submit(i), 10) for i in range(3)]
        await batcher.stop()
        return results

    assert asyncio.run(scenario()) == [0, 1, 2]


def _after_a_busy_batch_one_at_a_time(max_delay_s: float) -> tuple[list, list]:
    """(results, batches) of three requests sent 10 ms apart to a batcher whose last batch (of two) took long."""
    calls = []

    async def scenario():
        batcher = Batcher(lambda items: calls.append(items) or items, max_batch=3, max_delay_s=max_delay_s, max_queue=8)
        batcher._last_size, batcher._run_s = 2, 1e3  # as after a batch of two that took long
        batcher.start()
        tasks = []
        for i in range(3):
            tasks.append(asyncio.create_task(batcher.submit(i)))
            await asyncio.sleep(0.01)  # one at a time: without a wait, each goes alone
        results = await asyncio.wait_for(asyncio.gather(*tasks), 10)
        await batcher.stop()
        return results

    return asyncio.run(scenario()), calls


def test_after_a_busy_batch_the_next_waits_until_it_is_full():
    """When the last batch had company, a batch waits (up to the delay) for more requests: here it fills up."""
    results, calls = _after_a_busy_batch_one_at_a_time(60.0)
    assert results == [0, 1, 2] and calls == [[0, 1, 2]]


def test_with_no_delay_a_free_lane_sends_what_waits_at_once():
    """With max_delay 0 (a large model's default on 2 to 7 cores) a free lane never waits for company, even after a
    busy batch: requests that come one at a time go one at a time, so the clients fall into cohorts."""
    results, calls = _after_a_busy_batch_one_at_a_time(0.0)
    assert results == [0, 1, 2] and calls == [[0], [1], [2]]


def test_a_full_queue_refuses_at_once():
    release = threading.Event()

    async def scenario():
        batcher = Batcher(lambda items: release.wait(5) and items, max_batch=1, max_delay_s=0.0, max_queue=2)
        batcher.start()
        running = asyncio.create_task(batcher.submit("running"))
        await asyncio.sleep(0.05)  # taken off the queue, held in the decode thread
        queued = [asyncio.create_task(batcher.submit(i)) for i in range(2)]
        await asyncio.sleep(0)
        with pytest.raises(QueueFull):
            await batcher.submit("one too many")
        release.set()
        results = await asyncio.gather(running, *queued)
        await batcher.stop()
        return results

    assert asyncio.run(scenario()) == ["running", 0, 1]


def test_concurrent_http_requests_are_batched_and_the_queue_time_is_in_metrics(settings, predictor):
    from service.app import create_app

    # inline_max_ms 0: every request goes through the batcher, even one that finds the service idle
    app = create_app(settings.model_copy(update={"batching": True, "batch_max_size": 8, "inline_max_ms": 0}))
    guides = [(d, a) for d, a in zip(np.linspace(0.5, 10, 12), np.linspace(-10, 10, 12))]

    async def scenario():
        async with app.router.lifespan_context(app), httpx.AsyncClient(
                transport=httpx.ASGITransport(app=app), base_url="http://service") as client:
            replies = await asyncio.gather(*[client.post(
                "/predict", json={"displacement_mm": d, "angle_deg": a}, headers={"accept": "application/octet-stream"})
                for d, a in guides])
            return replies, (await client.get("/metrics")).text

    replies, metrics = asyncio.run(scenario())
    for (d, a), r in zip(guides, replies):
        assert r.status_code == 200
        got = np.frombuffer(r.content, dtype="<f4").reshape(-1, 3)
        np.testing.assert_array_equal(got, predictor.displacement(d, a) + predictor.nodes32)
    count = float(re.search(r"^predict_queue_seconds_count (\S+)", metrics, re.M).group(1))
    batches = float(re.search(r"^predict_batch_size_count (\S+)", metrics, re.M).group(1))
    assert count == len(guides) and batches < len(guides)  # every request queued; some shared a batch


@pytest.mark.parametrize("accept", ["application/octet-stream", "application/json"])
def test_replies_are_the_same_bytes_with_batching_on_and_off(settings, accept):
    """Concurrent full-mesh and marker requests through the batcher (every decode batched) and without it."""
    from service.app import create_app

    bodies = [{"displacement_mm": d, "angle_deg": a, **extra} for d, a, extra in [
        (5.0, 2.0, {}), (9.5, -7.0, {"region": "markers"}), (1.0, 3.0, {}), (3.0, 9.0, {"region": "markers"}),
        (10.0, -10.0, {}), (0.0, 0.0, {})]]

    async def replies(update):
        app = create_app(settings.model_copy(update=update))
        async with app.router.lifespan_context(app), httpx.AsyncClient(
                transport=httpx.ASGITransport(app=app), base_url="http://service") as client:
            got = await asyncio.gather(*[client.post("/predict", json=b, headers={"accept": accept}) for b in bodies])
            return [r.content for r in got], (await client.get("/metrics")).text

    on, metrics = asyncio.run(replies({"batching": True, "inline_max_ms": 0, "batch_lanes": 2}))
    off, _ = asyncio.run(replies({"batching": False}))
    inline, _ = asyncio.run(replies({"batching": True}))  # cheap decodes on the event loop
    assert on == off == inline
    assert float(re.search(r"^predict_batch_size_count (\S+)", metrics, re.M).group(1)) > 0


def test_lanes_run_batches_at_the_same_time():
    """With two lanes, a second batch starts while the first is still running (each waits for the other)."""
    both = threading.Barrier(2, timeout=5)

    def run_batch(items):
        both.wait()  # raises BrokenBarrierError unless two batches are in run_batch at once
        return items

    async def scenario():
        batcher = Batcher(run_batch, max_batch=1, max_delay_s=0.0, max_queue=8, lanes=2)
        batcher.start()
        results = await asyncio.gather(batcher.submit("a"), batcher.submit("b"))
        await batcher.stop()
        return results

    assert asyncio.run(scenario()) == ["a", "b"]


def test_a_cheap_batch_does_not_wait_for_company():
    """The delay is capped by the recent batch run time: after busy batches of a fast decode, a lone request
    goes without waiting out a 60 s max_delay."""
    async def scenario():
        batcher = Batcher(lambda items: items, max_batch=8, max_delay_s=60.0, max_queue=8)
        batcher._last_size, batcher._run_s = 4, 1e-4  # as after batches of four taking 0.1 ms
        batcher.start()
        result = await asyncio.wait_for(batcher.submit(1), 10)
        await batcher.stop()
        return result

    assert asyncio.run(scenario()) == 1


def test_a_batch_waits_only_for_the_next_preferred_size():
    calls = []

    async def scenario():
        batcher = Batcher(lambda items: calls.append(items) or items, max_batch=8, max_delay_s=60.0, max_queue=16,
                          preferred=[2])
        batcher._last_size, batcher._run_s = 2, 1e3
        batcher.start()
        tasks = []
        for i in range(2):
            tasks.append(asyncio.create_task(batcher.submit(i)))
            await asyncio.sleep(0.01)
        results = await asyncio.wait_for(asyncio.gather(*tasks), 10)
        await batcher.stop()
        return results

    assert asyncio.run(scenario()) == [0, 1] and calls == [[0, 1]]


def test_the_delay_counts_from_the_free_lane_not_from_the_first_arrival():
    """A request that waited through the last batch still waits (up to the delay) for company once its lane is
    free, so the clients whose replies were just sent join it: 0 waits through a 0.35 s batch of two, 1 arrives
    0.1 s after that batch ends, and with a 0.2 s delay both decode together (counted from 0's arrival, the delay
    would be over before the lane was free, and 1 would run alone)."""
    calls, release = [], threading.Event()

    def run_batch(items):
        calls.append(list(items))
        if items[0] == "first":
            release.wait(5)
        return items

    async def scenario():
        batcher = Batcher(run_batch, max_batch=8, max_delay_s=0.2, max_queue=16)
        batcher._run_s = 1e3  # the cap (a quarter of the recent run time) is far
        batcher.start()
        busy = [asyncio.create_task(batcher.submit(x)) for x in ("first", "second")]  # queued together: one batch
        await asyncio.sleep(0.05)
        early = asyncio.create_task(batcher.submit(0))  # waits while "first" runs
        await asyncio.sleep(0.3)
        await asyncio.get_running_loop().run_in_executor(None, release.set)
        await asyncio.sleep(0.1)
        late = asyncio.create_task(batcher.submit(1))
        results = await asyncio.wait_for(asyncio.gather(*busy, early, late), 10)
        await batcher.stop()
        return results

    assert asyncio.run(scenario()) == ["first", "second", 0, 1]
    assert calls == [["first", "second"], [0, 1]]
