"""Dynamic batching: requests that arrive within a few milliseconds of each other are generated in one call.

Each request carries its own seed, and the pipeline draws an item's noise from its own seed and length, so a
request's motion does not depend on the requests it was batched with. The event loop only queues and
gathers; generation runs on a worker (serve/worker.py): a thread, or (for `smf serve`) a supervised
process, so that its Python-heavy work (the rigid fit) does not hold the event loop's interpreter lock.
A job whose client has gone (its future cancelled) is dropped before it runs; timelines run one per call,
so that an abandoned one is dropped too.
"""

from __future__ import annotations

import asyncio
import logging
from collections import defaultdict

from ..limits import BATCH_SIZE
from .http_errors import ServeError, log_event
from .worker import Failure, Job


class DynamicBatcher:
    """Gathers jobs for up to ``wait_ms`` after the first (at most ``max_batch``) and runs them together;
    at most ``max_queue`` jobs wait (503 beyond). ``batch_sizes`` records every call's size."""

    def __init__(self, worker, *, max_batch: int = BATCH_SIZE, wait_ms: float = 5.0, max_queue: int = 256):
        if max_batch < 1 or wait_ms < 0 or max_queue < 0:
            raise ServeError(500, "max_batch must be >= 1, wait_ms and max_queue >= 0")
        self.worker, self.max_batch, self.wait, self.max_queue = worker, max_batch, wait_ms / 1000.0, max_queue
        self.batch_sizes: list[int] = []
        self.dropped = 0  # jobs whose client left before they ran
        self._queue: asyncio.Queue | None = None
        self._task: asyncio.Task | None = None

    @property
    def waiting(self) -> int:
        return 0 if self._queue is None else self._queue.qsize()

    async def submit(self, job: Job):
        """Queue ``job`` and wait for its ``MotionResult``; ServeError for a full queue or a failed job.
        Cancelling the caller cancels the job (it is dropped if it has not started)."""
        if self._task is None or self._task.done():
            self._queue = asyncio.Queue()
            self._task = asyncio.get_running_loop().create_task(self._run())
        if self._queue.qsize() >= self.max_queue:
            raise ServeError(503, f"the server is busy: {self._queue.qsize()} requests are waiting; try again "
                                  "shortly")
        future = asyncio.get_running_loop().create_future()
        self._queue.put_nowait((job, future))
        return await future

    async def _gather(self) -> list:
        """The next batch: the first job, every job already waiting (however long the window has run: under
        load the queue fills while the worker generates, and a busy event loop must not cut a batch short),
        and those that arrive within ``wait_ms`` of the first, up to ``max_batch``."""
        loop = asyncio.get_running_loop()
        batch = [await self._queue.get()]
        deadline = loop.time() + self.wait
        while len(batch) < self.max_batch:
            if not self._queue.empty():
                batch.append(self._queue.get_nowait())
                continue
            remaining = deadline - loop.time()
            if remaining <= 0:
                break
            try:
                batch.append(await asyncio.wait_for(self._queue.get(), remaining))
            except asyncio.TimeoutError:
                break
        return batch

    async def _run(self) -> None:
        while True:
            groups: dict[tuple, list] = defaultdict(list)
            for job, future in await self._gather():
                key = ("timeline", id(future)) if job.segments is not None else job.sampling
                groups[key].append((job, future))
            for items in groups.values():
                await self._run_group(items)

    async def _run_group(self, items: list) -> None:
        live = [(j, f) for j, f in items if not f.cancelled()]  # checked just before the group runs
        self.dropped += len(items) - len(live)
        if not live:
            return
        self.batch_sizes.append(len(live))
        try:
            outcomes = await asyncio.wrap_future(self.worker.submit([j for j, _ in live], self.max_batch))
        except ServeError as e:  # the worker itself failed (died, stopped): every job of the call
            outcomes = [Failure(e.status, e.message)] * len(live)
        except Exception as e:  # noqa: BLE001 - never leave a request unanswered
            log_event(logging.ERROR, "the worker call failed: %s: %s", type(e).__name__, e)
            outcomes = [Failure(500, f"generation failed ({type(e).__name__})")] * len(live)
        for (_, future), outcome in zip(live, outcomes):
            if future.done():
                continue
            if isinstance(outcome, Failure):
                future.set_exception(ServeError(outcome.status, outcome.message))
            else:
                future.set_result(outcome)

    def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
