"""Where generation runs: a worker that owns its pipeline and answers every job on its own.

:class:`ThreadWorker` generates with a pipeline given to it (tests, embedding); :class:`ProcessWorker` (what
`smf serve` uses) runs a supervised child process that loads the checkpoint itself, warms it, and is
restarted when it dies. Both take a batch of jobs with ``submit(jobs, max_batch)`` and return a
``concurrent.futures.Future`` of one outcome per job: a ``MotionResult`` or a :class:`Failure`.
A failing batch is re-run one job at a time, so one bad request never fails the others.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import queue
import threading
import time
import warnings
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

from ..core.errors import SMFError
from ..core.limits import FOOTSKATE, FOOTSKATE_MODES
from .http_errors import ServeError, log, log_event
from .server_limits import (WARM_STEPS, WORKER_BEAT_S, WORKER_BEAT_TIMEOUT_S, WORKER_CALL_BASE_S,
                            WORKER_CALL_PER_WORK_S, WORKER_MAX_FAILED_STARTS, WORKER_POLL_S,
                            WORKER_RESTART_DELAY_S, WORKER_START_TIMEOUT_S, WORKER_STOP_S)


@dataclass(frozen=True)
class Job:
    """One checked generation request: ``seconds`` within the model's range, or None (the model's length
    estimate, made where generation runs); ``segments`` for a timeline (POST /v1/timeline)."""

    prompt: str
    seconds: float | None
    seed: int
    guidance: float | None = None  # None: the model's
    steps: int | None = None  # None: the model's (a distilled student's own count)
    footskate: str = FOOTSKATE
    segments: tuple[tuple[str, float], ...] | None = None
    adapter: str | None = None  # None: the base model; else a loaded adapter's name
    path: object = None  # a root path to follow (stablemofusion.core.path_plan.Waypoints), or None
    cost: float = 0.0  # its work before it runs (stablemofusion.core.limits.request_cost): what the queue admits by

    @property
    def sampling(self) -> tuple:
        """How the job samples (its model and settings: adapter, guidance, steps, footskate): jobs alike are
        generated in one call."""
        return (self.adapter, self.guidance, self.steps, self.footskate)


@dataclass(frozen=True)
class ServedModel:
    """What the server knows of the model it serves before loading it: frame rate, shortest and longest motion of
    one window (frames), whether it is a distilled student, its default steps and guidance scale."""

    fps: float
    min_frames: int
    max_frames: int
    student: bool
    steps: int
    guidance: float
    version: str | None = None  # the model's version (a release's name), in every answer
    footskate: tuple[str, ...] = FOOTSKATE_MODES  # the footskate modes its runtime runs (health lists them)

    @classmethod
    def from_config(cls, config) -> "ServedModel":
        """From a torch checkpoint's CheckpointConfig."""
        from ..core.limits import GUIDANCE, STEPS

        return cls(config.fps, config.min_frames, config.max_frames, bool(config.student),
                   config.distil.sample_steps if config.student else STEPS,
                   GUIDANCE if config.guidance is None else config.guidance,
                   config.export.version if config.export is not None else None)

    @classmethod
    def of(cls, pipe) -> "ServedModel":
        """From a loaded :class:`~stablemofusion.pipelines.motion_pipeline.MotionPipeline` on either backend: its
        sizes and the settings a request without any resolves to."""
        b, s = pipe.backend, pipe.settings()
        return cls(b.fps, b.min_frames, b.max_frames, b.student, s.steps, s.guidance_scale, b.version,
                   b.footskate_modes)


@dataclass(frozen=True)
class Failure:
    """The outcome of a job that failed: its own HTTP status and one-line message."""

    status: int
    message: str


def generate_jobs(pipe, jobs: list[Job], max_batch: int) -> list:
    """Jobs of one ``sampling`` (guidance, steps, footskate) as one pipeline call (one seed per job), or
    timelines one by one."""
    first = jobs[0]
    if first.adapter is not None:
        pipe = pipe.variant(first.adapter)
    if first.segments is not None:
        return [pipe.timeline(list(j.segments), guidance_scale=j.guidance, steps=j.steps, seed=j.seed,
                              footskate=j.footskate) for j in jobs]
    paths = [j.path for j in jobs] if any(j.path is not None for j in jobs) else None
    return pipe([j.prompt for j in jobs], seconds=[j.seconds for j in jobs], seed=[j.seed for j in jobs],
                guidance_scale=first.guidance, steps=first.steps, footskate=first.footskate, batch_size=max_batch,
                path=paths)


def run_isolated(pipe, jobs: list[Job], max_batch: int) -> list:
    """One outcome per job: the batch as one call; if that fails, each job alone (its own failure)."""
    try:
        return _logged_warnings(generate_jobs, pipe, jobs, max_batch)
    except Exception as e:  # noqa: BLE001 - isolated below, job by job
        if len(jobs) == 1:
            return [_failure(jobs[0], e)]
    out = []
    for job in jobs:
        try:
            out += _logged_warnings(generate_jobs, pipe, [job], max_batch)
        except Exception as e:  # noqa: BLE001 - this job's own answer
            out.append(_failure(job, e))
    return out


def _failure(job: Job, e: Exception) -> Failure:
    if isinstance(e, SMFError):
        return Failure(422, str(e))
    log_event(logging.ERROR, "generation failed for prompt '%s': %s: %s", job.prompt, type(e).__name__, e)
    return Failure(500, f"generation failed ({type(e).__name__}); the request was not answered")


# not logged: a requested length rounded to a multiple of 4 frames, and libraries' notices
QUIET_WARNINGS = ("LengthClampedWarning", "DeprecationWarning", "FutureWarning")


def _logged_warnings(fn, *args):
    """Call ``fn``; its warnings (which quote prompts) go to the server's log, escaped."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = fn(*args)
    for w in caught:
        if w.category.__name__ not in QUIET_WARNINGS:
            log_event(logging.WARNING, "%s: %s", w.category.__name__, w.message)
    return out


def warm(pipe) -> None:
    """One short generation, so the first request does not pay for loading the text encoder and kernels."""
    pipe(["a person walks forward"], frames=[pipe.min_frames], seed=[0], steps=WARM_STEPS)


class ThreadWorker:
    """Generates with ``pipe`` on one thread of this process (tests and embedding)."""

    def __init__(self, pipe):
        self.pipe, self.model = pipe, ServedModel.of(pipe)
        self.adapters = tuple(getattr(pipe, "variants", ()))  # the adapters requests may name
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="smf-generate")
        self._warm: Future | None = None

    @property
    def executor(self) -> ThreadPoolExecutor:
        """The one thread that generates with ``pipe`` (streams on the same pipeline use it too: a model is
        not called from two threads at once)."""
        return self._pool

    def start(self) -> None:
        if self._warm is None:
            self._warm = self._pool.submit(warm, self.pipe)

    def submit(self, jobs: list[Job], max_batch: int) -> Future:
        self.start()
        return self._pool.submit(run_isolated, self.pipe, jobs, max_batch)

    def health(self) -> dict:
        ready = self._warm is not None and self._warm.done() and self._warm.exception() is None
        state = "ready" if ready else "failed" if self._warm is not None and self._warm.done() else "starting"
        return {"state": state, "pid": os.getpid(), "model_loaded": True, "warm": ready, "busy": False, "restarts": 0}

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


@dataclass(frozen=True)
class WorkerSpec:
    """What the worker process loads: checkpoint (None: the shipped model; with the portable engine, a graphs folder
    or a model folder holding one), device, threads, engine ('onnx': the ONNX backend, no torch)."""

    checkpoint: str | None
    device: str | None = None
    threads: int = 2
    engine: str = "auto"
    adapters: tuple[str, ...] = ()  # adapter files, each served as a model of its own beside the base
    teacher: bool = False  # the portable engine: the graphs' teacher (a torch checkpoint names its folder)


def call_deadline(jobs: list) -> float:
    """Seconds a worker call for ``jobs`` may take: WORKER_CALL_BASE_S plus WORKER_CALL_PER_WORK_S per second of
    motion per sampling step asked for (a path's length as its seconds; a length or steps left to the model count as a
    window, 10 steps)."""
    work = 0.0
    for job in jobs:
        path = getattr(job, "path", None)
        seconds = (getattr(job, "seconds", None) or sum(s for _, s in (getattr(job, "segments", None) or ()))
                   or (path.seconds(job.prompt) if path is not None else None) or 10.0)
        work += seconds * (getattr(job, "steps", None) or 10)
    return WORKER_CALL_BASE_S + WORKER_CALL_PER_WORK_S * work


def heartbeat(beat) -> None:
    """Mark ``beat`` (a shared double) with the time every WORKER_BEAT_S, on a thread of its own, for ever."""
    def run():
        while True:
            beat.value = time.monotonic()
            time.sleep(WORKER_BEAT_S)

    threading.Thread(target=run, name="smf-heartbeat", daemon=True).start()


def child_loop(conn, spec: WorkerSpec, name: str, warm_up, handle, beat=None) -> None:
    """The body of a worker process: mark ``beat`` while it lives, load and warm its own pipeline
    (``warm_up(pipe)``), then answer each message with ``handle(pipe, message)`` until told to stop or the server
    goes away."""
    import signal

    if beat is not None:
        heartbeat(beat)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group: the server stops the worker
    logging.basicConfig(level=logging.INFO, format=f"smf serve {name}: %(levelname)s %(message)s")
    pipe = load_pipeline(spec)
    conn.send(("loaded", None))
    warm_up(pipe)
    conn.send(("ready", None))
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        conn.send(handle(pipe, message))


def load_pipeline(spec: WorkerSpec):
    """The pipeline a worker process serves, on the backend its engine means (:func:`~stablemofusion.backends.
    backend_for`), with its adapters (torch) each served as a model of its own."""
    from ..pipelines.motion_pipeline import MotionPipeline

    pipe = MotionPipeline.from_pretrained(spec.checkpoint, engine=spec.engine, teacher=spec.teacher,
                                          threads=spec.threads, **({"device": spec.device} if spec.device else {}))
    if spec.adapters:
        pipe.add_variants(spec.adapters)
    return pipe


def _child_main(conn, spec: WorkerSpec, beat=None) -> None:
    """The batch worker process: batches of jobs, each answered alone when the batch fails."""
    child_loop(conn, spec, "worker", warm, lambda pipe, message: run_isolated(pipe, *message), beat)


class _Died(Exception):
    """The worker process ended."""


class ProcessWorker:
    """A supervised worker process: started (and restarted after it dies) by a supervising thread; jobs in
    flight when it dies fail with a 503; after ``WORKER_MAX_FAILED_STARTS`` deaths before ready it gives up."""

    def __init__(self, spec: WorkerSpec, model: ServedModel, adapters: tuple[str, ...] = ()):
        self.spec, self.model = spec, model  # what the server knows of the model before the process loads it
        self.adapters = tuple(adapters)  # the names of spec.adapters: what requests may name
        self._inbox: queue.Queue = queue.Queue()
        self._state, self._loaded, self._warm, self._restarts, self._busy = "stopped", False, False, 0, False
        self._proc = None
        self._beat = None  # the process's heartbeat (a shared double: time.monotonic() of its last mark)
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._lock = threading.Lock()

    def start(self) -> None:
        with self._lock:
            if self._thread is None:
                self._state = "starting"
                self._thread = threading.Thread(target=self._supervise, name="smf-worker-supervisor", daemon=True)
                self._thread.start()

    def submit(self, jobs: list[Job], max_batch: int) -> Future:
        self.start()
        future: Future = Future()
        if self._state == "failed" or self._stopping.is_set():
            future.set_exception(ServeError(503, f"the generation worker is {self._state}; see the server log"))
        else:
            self._inbox.put((jobs, max_batch, future))
        return future

    def health(self) -> dict:
        alive = self._proc is not None and self._proc.is_alive()
        # between the worker's death and the supervisor noticing it, it is not ready (never a stale "ready")
        state = "restarting" if self._state == "ready" and not alive else self._state
        state = "unresponsive" if state == "ready" and self._silent() else state
        return {"state": state, "pid": self._proc.pid if alive else None, "model_loaded": self._loaded,
                "warm": self._warm, "busy": self._busy, "restarts": self._restarts}

    def close(self) -> None:
        """Stop the worker now (what SIGTERM leads to): jobs still waiting get a 503."""
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(WORKER_STOP_S * 3)
        self._stop_process()
        self._fail_waiting("the server is shutting down")
        self._state = "stopped"

    # the supervising thread
    def _supervise(self) -> None:
        failed_starts = 0
        while not self._stopping.is_set():
            conn = self._spawn()
            try:
                self._await_ready(conn)
                failed_starts = 0
                self._serve(conn)
            except _Died as e:
                if self._stopping.is_set():
                    break
                failed_starts += 0 if self._warm else 1
                self._restarts += 1
                log_event(logging.ERROR, "the generation worker died (%s); restarting", e)
                if failed_starts >= WORKER_MAX_FAILED_STARTS:
                    self._state = "failed"
                    self._fail_waiting("the generation worker cannot start; see the server log")
                    log_event(logging.ERROR, "the generation worker died %s times before ready; giving up",
                              failed_starts)
                    return
                self._down()
                time.sleep(WORKER_RESTART_DELAY_S)
            finally:
                conn.close()
                self._stop_process()

    def _down(self) -> None:
        """The process is gone: health says so at once (before any request hears of it)."""
        self._state, self._loaded, self._warm = "restarting", False, False

    child_main = staticmethod(_child_main)  # the process's body (module level: spawn pickles it by name)
    process_name = "smf-worker"

    def _silent(self) -> float | None:
        """Seconds since the process's last heartbeat when more than WORKER_BEAT_TIMEOUT_S (it is stopped or
        frozen), else None."""
        beat = self._beat
        if beat is None or not self._warm:
            return None
        quiet = time.monotonic() - beat.value
        return quiet if quiet > WORKER_BEAT_TIMEOUT_S else None

    def _spawn(self):
        ctx = multiprocessing.get_context("spawn")  # no forked threads (torch's, ONNX Runtime's)
        parent, child = ctx.Pipe()
        self._beat = ctx.Value("d", time.monotonic(), lock=False)
        self._proc = ctx.Process(target=self.child_main, args=(child, self.spec, self._beat), name=self.process_name,
                                 daemon=True)
        self._proc.start()
        child.close()
        return parent

    def _await_ready(self, conn) -> None:
        deadline = time.monotonic() + WORKER_START_TIMEOUT_S
        while not self._warm:
            if time.monotonic() > deadline:
                raise _Died(f"not ready after {WORKER_START_TIMEOUT_S:g} s")
            message, _ = self._receive(conn)
            if message == "loaded":
                self._loaded, self._state = True, "warming"
            elif message == "ready":
                self._warm, self._state = True, "ready"
                log.info("the generation worker is ready (pid %s)", self._proc.pid)

    def _serve(self, conn) -> None:
        while not self._stopping.is_set():
            try:
                jobs, max_batch, future = self._inbox.get(timeout=WORKER_POLL_S)
            except queue.Empty:
                if not self._proc.is_alive():
                    raise _Died(f"exit code {self._proc.exitcode}") from None
                quiet = self._silent()
                if quiet is not None:
                    raise _Died(f"unresponsive: no heartbeat for {quiet:.1f} s") from None
                continue
            if not future.set_running_or_notify_cancel():
                continue
            try:
                self._busy = True
                conn.send((jobs, max_batch))
                future.set_result(self._receive(conn, time.monotonic() + call_deadline(jobs)))
            except _Died:
                self._down()
                future.set_exception(ServeError(503, "the generation worker stopped while generating this "
                                                     "request; it is being restarted, retry shortly"))
                raise
            except OSError as e:
                self._down()
                future.set_exception(ServeError(503, "the generation worker stopped; retry shortly"))
                raise _Died(str(e)) from None
            finally:
                self._busy = False

    def _receive(self, conn, deadline: float | None = None):
        """The process's next message; _Died when it ends, stops beating, or passes ``deadline``."""
        while not conn.poll(WORKER_POLL_S):
            if self._stopping.is_set():
                raise _Died("the server is stopping")
            if not self._proc.is_alive():
                raise _Died(f"exit code {self._proc.exitcode}")
            quiet = self._silent()
            if quiet is not None:
                raise _Died(f"unresponsive: no heartbeat for {quiet:.1f} s")
            if deadline is not None and time.monotonic() > deadline:
                raise _Died("no answer within the call's deadline")
        try:
            return conn.recv()
        except (EOFError, OSError):
            self._proc.join(WORKER_STOP_S)
            raise _Died(f"exit code {self._proc.exitcode}") from None

    def _stop_process(self) -> None:
        proc = self._proc
        if proc is None or not proc.is_alive():
            return
        proc.terminate()
        proc.join(WORKER_STOP_S)
        if proc.is_alive():
            proc.kill()
            proc.join(WORKER_STOP_S)

    def _fail_waiting(self, message: str) -> None:
        while True:
            try:
                _, _, future = self._inbox.get_nowait()
            except queue.Empty:
                return
            if future.set_running_or_notify_cancel():
                future.set_exception(ServeError(503, message))
