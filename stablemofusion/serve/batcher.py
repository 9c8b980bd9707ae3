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
import math
import time
from collections import defaultdict, deque

from ..core.limits import BATCH_SIZE
from .http_errors import ServeError, log_event
from .server_limits import LIGHT_COST, MAX_QUEUED_COST, MAX_REQUEST_COST
from .worker import Failure, Job


class DynamicBatcher:
    """Gathers jobs for up to ``wait_ms`` after the first (at most ``max_batch``, at most ``max_batch_cost`` of work)
    and runs them together. Jobs of at most ``light_cost`` wait in a lane of their own; when both lanes hold jobs,
    batches alternate between them, so a light job waits for at most one heavy batch. Admission is by work: at most
    ``max_queue`` jobs wait, and in each lane at most ``max_queued_cost`` of work (503 with Retry-After beyond), so
    heavy jobs never fill the queue for light ones. ``batch_sizes`` records every call's size."""

    def __init__(self, worker, *, max_batch: int = BATCH_SIZE, wait_ms: float = 5.0, max_queue: int = 256,
                 max_queued_cost: float = MAX_QUEUED_COST, light_cost: float = LIGHT_COST,
                 max_batch_cost: float = MAX_REQUEST_COST):
        if max_batch < 1 or wait_ms < 0 or max_queue < 0 or max_queued_cost < 0 or max_batch_cost <= 0:
            raise ServeError(500, "max_batch must be >= 1, max_batch_cost > 0, wait_ms, max_queue and "
                                  "max_queued_cost >= 0")
        self.worker, self.max_batch, self.wait, self.max_queue = worker, max_batch, wait_ms / 1000.0, max_queue
        self.max_queued_cost, self.light_cost, self.max_batch_cost = max_queued_cost, light_cost, max_batch_cost
        self.batch_sizes: list[int] = []
        self.dropped = 0  # jobs whose client left before they ran
        self.refused = 0  # jobs refused for a full queue
        self.lane_cost = [0.0, 0.0]  # the work of the jobs waiting in each lane
        self.rate: float | None = None  # work done per second, a running mean over the calls made (for Retry-After)
        self._lanes: tuple[deque, deque] = (deque(), deque())  # light, heavy: (job, future) in arrival order
        self._heavy_turn = False
        self._arrived: asyncio.Event | None = None
        self._task: asyncio.Task | None = None

    @property
    def waiting(self) -> int:
        return len(self._lanes[0]) + len(self._lanes[1])

    @property
    def queued_cost(self) -> float:
        """The work of the jobs waiting."""
        return self.lane_cost[0] + self.lane_cost[1]

    def _lane(self, job: Job) -> int:
        return 0 if job.cost <= self.light_cost else 1

    def _admits(self, job: Job) -> bool:
        lane = self._lane(job)
        return self.waiting < self.max_queue and (not self._lanes[lane]
                                                   or self.lane_cost[lane] + job.cost <= self.max_queued_cost)

    @property
    def saturated(self) -> bool:
        """Whether a request of the heaviest kind would be refused now."""
        return self.waiting >= self.max_queue or (
            bool(self._lanes[1]) and self.lane_cost[1] + self.max_batch_cost > self.max_queued_cost)

    def retry_after(self) -> int:
        """Seconds until the work waiting now is done, at the rate measured so far (1 before any call)."""
        return max(1, math.ceil(self.queued_cost / self.rate)) if self.rate else 1

    def queue_state(self) -> dict:
        """The queue as GET /v1/health shows it."""
        return {"waiting": self.waiting, "light": len(self._lanes[0]), "heavy": len(self._lanes[1]),
                "queued_cost": round(self.queued_cost, 1), "max_queued_cost": self.max_queued_cost,
                "saturated": self.saturated, "refused": self.refused,
                "retry_after_s": self.retry_after() if self.waiting else 0}

    async def submit(self, job: Job):
        """Queue ``job`` and wait for its ``MotionResult``; ServeError for a full queue (503, Retry-After) or a
        failed job. Cancelling the caller cancels the job (it is dropped if it has not started)."""
        if self._task is None or self._task.done():
            self._arrived = asyncio.Event()
            self._task = asyncio.get_running_loop().create_task(self._run())
        if not self._admits(job):
            self.refused += 1
            raise ServeError(503, f"the server is busy: {self.waiting} requests ({self.queued_cost:.0f} units of "
                                  f"work) are waiting; try again in {self.retry_after()} s", self.retry_after())
        future = asyncio.get_running_loop().create_future()
        lane = self._lane(job)
        self._lanes[lane].append((job, future))
        self.lane_cost[lane] += job.cost
        self._arrived.set()
        return await future

    def _take(self, lane: int):
        job, future = self._lanes[lane].popleft()
        self.lane_cost[lane] = max(0.0, self.lane_cost[lane] - job.cost) if self._lanes[lane] else 0.0
        return job, future

    async def _gather(self) -> list:
        """The next batch, from one lane (light first; the heavy lane's turn after a light batch when it waits): its
        first job, every job of that lane already waiting (however long the window has run: under load the queue
        fills while the worker generates, and a busy event loop must not cut a batch short), and those that arrive
        within ``wait_ms`` of the first, up to ``max_batch`` jobs and ``max_batch_cost`` of work."""
        loop = asyncio.get_running_loop()
        while not self.waiting:
            self._arrived.clear()
            await self._arrived.wait()
        light, heavy = self._lanes
        lane = 1 if heavy and (self._heavy_turn or not light) else 0
        batch = [self._take(lane)]
        cost = batch[0][0].cost
        deadline = loop.time() + self.wait
        while len(batch) < self.max_batch:
            queue = self._lanes[lane]
            if queue:
                if cost + queue[0][0].cost > self.max_batch_cost:
                    break
                batch.append(self._take(lane))
                cost += batch[-1][0].cost
                continue
            remaining = deadline - loop.time()
            if remaining <= 0:
                break
            self._arrived.clear()
            try:
                await asyncio.wait_for(self._arrived.wait(), remaining)
            except asyncio.TimeoutError:
                break
        self._heavy_turn = lane == 0 and bool(heavy)
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
        started = time.monotonic()
        try:
            outcomes = await asyncio.wrap_future(self.worker.submit([j for j, _ in live], self.max_batch))
            work, took = sum(j.cost for j, _ in live), time.monotonic() - started
            if work > 0 and took > 0:  # the work done per second, for Retry-After
                self.rate = work / took if self.rate is None else 0.8 * self.rate + 0.2 * work / took
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
