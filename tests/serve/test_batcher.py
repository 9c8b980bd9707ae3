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
