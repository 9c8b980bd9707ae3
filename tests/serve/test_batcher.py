"""The dynamic batcher takes every job already waiting, even when its window has passed (a busy event loop)."""

import asyncio
from concurrent.futures import Future

from stablemofusion.serve.batcher import DynamicBatcher
from stablemofusion.serve.worker import Job


class EchoWorker:
    """Answers each job with its prompt at once."""

    def submit(self, jobs, max_batch):
        f = Future()
        f.set_result([j.prompt for j in jobs])
        return f


def test_jobs_already_waiting_join_the_batch_after_the_window():
    async def main():
        batcher = DynamicBatcher(EchoWorker(), max_batch=32, wait_ms=0)
        jobs = [Job(f"p{i}", 2.0, i) for i in range(40)]
        out = await asyncio.gather(*[batcher.submit(j) for j in jobs])  # all queued before the batcher runs
        batcher.close()
        return out, batcher.batch_sizes

    out, sizes = asyncio.run(main())
    assert out == [f"p{i}" for i in range(40)]
    assert sizes == [32, 8]


class SlowWorker:
    """Answers each call after ``seconds`` on a thread, recording the prompts of every call."""

    def __init__(self, seconds: float):
        import concurrent.futures

        self.seconds, self.calls = seconds, []
        self.pool = concurrent.futures.ThreadPoolExecutor(1)

    def submit(self, jobs, max_batch):
        import time

        def run():
            time.sleep(self.seconds)
            self.calls.append([j.prompt for j in jobs])
            return [j.prompt for j in jobs]

        return self.pool.submit(run)


def test_a_light_job_waits_for_one_heavy_batch_however_many_are_queued():
    """64 heavy jobs queued, then a light one: batches hold at most one request's worth of work and alternate
    between the lanes, so the light job runs second, not after the 64."""
    async def main():
        worker = SlowWorker(0.01)
        batcher = DynamicBatcher(worker, max_batch=32, wait_ms=0, max_queued_cost=1e9, light_cost=300,
                                 max_batch_cost=2000)
        heavy = [asyncio.ensure_future(batcher.submit(Job(f"heavy{i}", 100.0, i, cost=1500.0))) for i in range(64)]
        await asyncio.sleep(0)
        light = await batcher.submit(Job("light", 4.0, 0, cost=24.0))
        done_heavy = sum(h.done() for h in heavy)
        await asyncio.gather(*heavy)
        batcher.close()
        return light, done_heavy, worker.calls

    light, done_heavy, calls = asyncio.run(main())
    assert light == "light" and done_heavy <= 2  # at most the running heavy batch and one more
    assert all(len(c) == 1 for c in calls if c[0].startswith("heavy"))  # 1,500 + 1,500 > 2,000 a batch
    assert sum(len(c) for c in calls) == 65


class GatedWorker:
    """Answers each call once ``gate`` is set (no clock involved)."""

    def __init__(self):
        import concurrent.futures
        import threading

        self.gate = threading.Event()
        self.pool = concurrent.futures.ThreadPoolExecutor(1)

    def submit(self, jobs, max_batch):
        def run():
            self.gate.wait(60)
            return [j.prompt for j in jobs]

        return self.pool.submit(run)


def test_work_past_the_queue_budget_is_refused_with_retry_after():
    from stablemofusion.serve.http_errors import ServeError

    async def until(condition):
        while not condition():
            await asyncio.sleep(0.001)

    async def main():
        worker = GatedWorker()
        batcher = DynamicBatcher(worker, max_batch=1, wait_ms=0, max_queued_cost=3000, max_batch_cost=2000)
        first = [asyncio.ensure_future(batcher.submit(Job("h0", 100.0, 0, cost=1400.0)))]
        await until(lambda: batcher.batch_sizes)  # it runs (held at the gate)
        first += [asyncio.ensure_future(batcher.submit(Job(f"h{i}", 100.0, i, cost=1400.0))) for i in (1, 2)]
        await until(lambda: batcher.waiting == 2)  # two wait: 2,800 queued
        state = batcher.queue_state()
        try:
            await batcher.submit(Job("one more", 100.0, 9, cost=1400.0))
        except ServeError as e:
            refused = e
        small = asyncio.ensure_future(batcher.submit(Job("small", 2.0, 9, cost=12.0)))  # the light lane has room
        await until(lambda: batcher.waiting == 3)
        worker.gate.set()
        out = await asyncio.gather(*first, small)
        batcher.close()
        return state, refused, out, batcher.queue_state()

    state, refused, out, after = asyncio.run(main())
    assert state["waiting"] == 2 and state["queued_cost"] == 2800 and state["saturated"]
    assert refused.status == 503 and refused.retry_after >= 1 and "units of work" in refused.message
    assert out == ["h0", "h1", "h2", "small"] or sorted(out) == sorted(["h0", "h1", "h2", "small"])
    assert after["refused"] == 1 and not after["saturated"] and after["waiting"] == 0
