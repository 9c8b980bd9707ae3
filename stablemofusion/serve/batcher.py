"""Dynamic batching: requests that arrive within a few milliseconds of each other are generated in one call.

Each request carries its own seed, and the pipeline draws an item's noise from its own seed and length
(``MotionPipeline.denoise`` with one seed per item), so a request's motion does not depend on the requests it
was batched with. The event loop only queues and gathers; the pipeline runs on one worker: a thread, or (for
`smf serve`) a separate process, so that its Python-heavy work (the rigid fit) does not hold the event loop's
interpreter lock while requests arrive (with a thread, 200 concurrent requests on the 2-core CPU formed
batches of at most 2).
"""

from __future__ import annotations

import asyncio
import multiprocessing
from collections import defaultdict
from concurrent.futures import Executor, ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import dataclass

from ..errors import SMFError


class QueueFull(SMFError):
    """The server's queue of waiting requests is full (HTTP 503)."""


@dataclass(frozen=True)
class Job:
    """One generation request, validated: ``frames`` within the model's range, or None (the model's length
    estimate, made in the worker)."""

    prompt: str
    frames: int | None
    seed: int
    guidance: float = 2.5
    steps: int = 10
    footskate: str = "off"
    segments: tuple[tuple[str, float], ...] | None = None  # a timeline (POST /v1/timeline) instead of one prompt

    @property
    def key(self) -> tuple:
        """Requests with the same key can share a sampling call (timelines run one by one)."""
        return self.guidance, self.steps, self.footskate, self.segments is not None


def generate_jobs(pipe, jobs: list[Job], max_batch: int) -> list:
    """Run jobs sharing one key as one pipeline call (one seed per job); timelines one after another."""
    first = jobs[0]
    if first.segments is not None:
        return [pipe.timeline(list(j.segments), guidance_scale=j.guidance, steps=j.steps, seed=j.seed,
                              footskate=j.footskate) for j in jobs]
    return pipe([j.prompt for j in jobs], frames=[j.frames for j in jobs], seed=[j.seed for j in jobs],
                guidance_scale=first.guidance, steps=first.steps, footskate=first.footskate, batch_size=max_batch)


_WORKER_PIPE = None  # the pipeline of a worker process


def _worker_init(checkpoint: str | None, device: str | None, threads: int, engine: str = "auto") -> None:
    global _WORKER_PIPE
    import torch

    from ..pipeline import MotionPipeline

    torch.set_num_threads(threads)
    _WORKER_PIPE = MotionPipeline.from_pretrained(checkpoint, device=device, engine=engine)


def _worker_run(jobs: list[Job], max_batch: int) -> list:
    return generate_jobs(_WORKER_PIPE, jobs, max_batch)


def process_executor(checkpoint: str | None, device: str | None = None, threads: int = 2,
                     engine: str = "auto") -> Executor:
    """One worker process that loads the checkpoint itself (spawned: no forked torch threads)."""
    return ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init, initargs=(checkpoint, device, threads, engine))


class DynamicBatcher:
    """Gathers jobs for up to ``wait_ms`` after the first (at most ``max_batch``) and runs them together;
    at most ``max_queue`` jobs wait (:class:`QueueFull` beyond). ``batch_sizes`` records every call's size.
    ``executor``: where the pipeline runs; default one thread with ``pipe``; or :func:`process_executor`."""

    def __init__(self, pipe, *, max_batch: int = 32, wait_ms: float = 5.0, max_queue: int = 256,
                 executor: Executor | None = None):
        if max_batch < 1 or wait_ms < 0 or max_queue < 0:
            raise SMFError("max_batch must be >= 1, wait_ms and max_queue >= 0")
        self.pipe, self.max_batch, self.wait, self.max_queue = pipe, max_batch, wait_ms / 1000.0, max_queue
        self.batch_sizes: list[int] = []
        self._queue: asyncio.Queue | None = None
        self._task: asyncio.Task | None = None
        self._in_process = executor is not None
        self._executor = executor or ThreadPoolExecutor(max_workers=1, thread_name_prefix="smf-generate")

    @property
    def waiting(self) -> int:
        return 0 if self._queue is None else self._queue.qsize()

    async def submit(self, job: Job):
        """Queue ``job`` and wait for its :class:`~stablemofusion.pipeline.MotionResult`."""
        if self._task is None or self._task.done():
            self._queue = asyncio.Queue()
            self._task = asyncio.get_running_loop().create_task(self._worker())
        if self._queue.qsize() >= self.max_queue:
            raise QueueFull(f"the server is busy: {self._queue.qsize()} requests are waiting; try again shortly")
        future = asyncio.get_running_loop().create_future()
        self._queue.put_nowait((job, future))
        return await future

    async def _worker(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            batch = [await self._queue.get()]
            deadline = loop.time() + self.wait
            while len(batch) < self.max_batch:
                try:
                    batch.append(await asyncio.wait_for(self._queue.get(), max(0.0, deadline - loop.time())))
                except asyncio.TimeoutError:
                    break
            groups: dict[tuple, list] = defaultdict(list)
            for job, future in batch:
                groups[job.key].append((job, future))
            for items in groups.values():
                live = [(j, f) for j, f in items if not f.cancelled()]
                if not live:
                    continue
                self.batch_sizes.append(len(live))
                jobs = [j for j, _ in live]
                try:
                    if self._in_process:
                        results = await loop.run_in_executor(self._executor, _worker_run, jobs, self.max_batch)
                    else:
                        results = await loop.run_in_executor(self._executor, generate_jobs, self.pipe, jobs,
                                                             self.max_batch)
                except Exception as e:  # noqa: BLE001 - handed to every waiting request
                    for _, f in live:
                        if not f.done():
                            f.set_exception(e)
                    continue
                for (_, f), r in zip(live, results):
                    if not f.done():
                        f.set_result(r)

    def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
        self._executor.shutdown(wait=False, cancel_futures=True)
