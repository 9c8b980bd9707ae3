"""Live streams over a WebSocket (``/v1/stream``): one endless motion per connection that follows the prompt
the client sends (:mod:`stablemofusion.pipelines.stream`).

    client -> server  {"prompt": "...", "seed"?: N, "guidance"?: G}   the first starts the stream, later ones
                                                                      change the prompt from the next window
                      {"stop": true}                                  ends the stream (the server closes)
    server -> client  {"type": "frames", "start": N, "fps": 20, "prompt_index": K, "joints": [n][22][3],
                       "contacts": [4][n] (0/1: the planted feet, left ankle, left toe, right ankle, right toe)}
                      {"type": "error", "error": "<one line>"}        a bad message: the stream goes on

Where it runs: windows are made by a stream worker of their own (not the batched HTTP worker, whose queue
could hold a live stream up for seconds): :class:`ThreadStreamWorker` on a thread (tests, embedding) or, for
`smf serve`, :class:`StreamProcessWorker`, a supervised process like the batch worker. The event loop's
:class:`StreamHub` gathers the windows every connection needs into one worker call (windows of several
streams are denoised as one batch; a connection with less than STREAM_AHEAD_S + STREAM_JOIN_S made ahead joins
a call as it starts), and each connection (:class:`StreamSession`) is paced by the clock:
it keeps windows made until its frames play STREAM_AHEAD_S ahead of play time (a slow window on a loaded CPU
makes no frame late), but sends frames at most STREAM_SEND_LEAD_S ahead of their play time (a few frames a
message); the frames made and not sent wait in its :class:`FrameBuffer`. A new prompt cuts that buffer back
(:func:`cut_frame`: past the frames sent, and far enough ahead for the window to come in time) and the stream
worker cuts the stream back to the same frame (:meth:`MotionStream.cut`) before making the next window with the
new prompt: the prompt shows a few tenths of a second after it came, not after the whole buffer. At most
``max_streams`` streams at once.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
from pydantic import BaseModel

from ..core import limits
from .checks import STRICT, checked, check_prompt, parse_body
from .http_errors import ServeError, log_event
from .server_limits import (MAX_STREAM_MESSAGE_BYTES, MAX_STREAM_MESSAGES, MAX_STREAM_SECONDS,
                            MAX_STREAMS, STREAM_AHEAD_S, STREAM_DECIMALS, STREAM_GATHER_S, STREAM_JOIN_S,
                            STREAM_MESSAGE_FRAMES, STREAM_MESSAGE_WINDOW_S, STREAM_RECENT_WINDOWS, STREAM_SEND_LEAD_S,
                            STREAM_START_TIMEOUT_S, STREAM_SWITCH_FACTOR, WARM_STEPS)
from ..core.motion_stream import advance
from .worker import Failure, ProcessWorker, child_loop

def _now() -> float:
    """The event loop's clock (time.monotonic in a real loop; tests run the streams on a virtual one)."""
    return asyncio.get_running_loop().time()


TRY_LATER = 1013  # WebSocket close code: the server is at its stream limit
SERVER_ERROR = 1011  # WebSocket close code: the stream cannot go on


class StreamMessage(BaseModel):
    """One client message: a prompt (with an optional seed and guidance) or a stop."""

    model_config = STRICT

    prompt: str | None = None
    seed: int | None = None  # ranges: stablemofusion/core/limits.py
    guidance: float | None = None
    stop: bool | None = None


@dataclass(frozen=True)
class StreamJob:
    """One window of stream ``sid`` (``prompt`` a new prompt, or None: the same; ``new``: the stream's first,
    which opens it; ``cut``: first cut the stream back to that frame), or its end (``close``)."""

    sid: int
    prompt: str | None = None
    seed: int | None = None
    guidance: float | None = None
    close: bool = False
    new: bool = False
    cut: int | None = None


@dataclass(frozen=True)
class StreamFrames:
    """The outcome of a window: frames ``start`` .. of the stream, ``joints`` (n, 22, 3) float32 metres,
    ``contacts`` (n, 4) bool the planted feet (:class:`~stablemofusion.core.motion_stream.Chunk`; None: not known)."""

    start: int
    joints: np.ndarray
    contacts: np.ndarray | None = None


def run_stream_jobs(pipe, streams: dict, jobs: list[StreamJob]) -> list:
    """Apply ``jobs`` to the open ``streams`` (sid -> MotionStream) of ``pipe``: one outcome per job (a
    :class:`StreamFrames`, None for a close, or a :class:`Failure`); the windows in one batched call."""
    out: list = [None] * len(jobs)
    live = []
    closing = {job.sid for job in jobs if job.close}  # a stream closed in this call makes no window in it
    for i, job in enumerate(jobs):
        try:
            if job.close:
                streams.pop(job.sid, None)
            elif job.sid in closing:
                continue  # its client has gone: None, as for the close
            elif job.new:
                streams[job.sid] = pipe.stream(job.prompt, seed=job.seed, guidance_scale=job.guidance)
                live.append(i)
            elif job.sid not in streams:
                raise ServeError(500, "the stream is gone (its worker restarted); start a new one")
            else:
                if job.cut is not None:
                    streams[job.sid].cut(job.cut)
                if job.prompt is not None:
                    streams[job.sid].set_prompt(job.prompt, seed=job.seed, guidance_scale=job.guidance)
                live.append(i)
        except Exception as e:  # noqa: BLE001 - this job's own answer
            out[i] = _failure(e)
    if live:
        _advance_isolated(pipe, streams, jobs, live, out)
    return out


def _advance_isolated(pipe, streams: dict, jobs: list[StreamJob], live: list[int], out: list) -> None:
    """The windows of jobs ``live`` in one call; if it fails, each alone (a failing stream is dropped)."""
    for group in [live] + ([[i] for i in live] if len(live) > 1 else []):
        try:
            chunks = advance([streams[jobs[i].sid] for i in group])
        except Exception as e:  # noqa: BLE001 - the batch: each alone next; one stream: its own failure
            if len(group) == 1:
                out[group[0]] = _failure(e)
                streams.pop(jobs[group[0]].sid, None)
            continue
        for i, chunk in zip(group, chunks):
            out[i] = StreamFrames(chunk.start, chunk.joints, chunk.contacts)
        if group is live:
            return


def _failure(e: Exception) -> Failure:
    if isinstance(e, ServeError):
        return Failure(e.status, e.message)
    log_event(logging.ERROR, "a stream window failed: %s: %s", type(e).__name__, e)
    return Failure(500, f"generation failed ({type(e).__name__})")


def warm_streams(pipe) -> None:
    """One short stream window, so the first stream does not pay for loading the text encoder."""
    pipe.stream("a person walks forward", seed=0, steps=WARM_STEPS).__next__()


class ThreadStreamWorker:
    """Makes stream windows with ``pipe`` on one thread of this process (tests and embedding): ``executor``,
    the thread of the HTTP worker that shares ``pipe`` (a model is not called from two threads at once), or
    a thread of its own."""

    def __init__(self, pipe, executor: ThreadPoolExecutor | None = None):
        self.pipe = pipe
        self._own = executor is None
        self._pool = executor or ThreadPoolExecutor(max_workers=1, thread_name_prefix="smf-stream")
        self._streams: dict = {}
        self._warm: Future | None = None

    def start(self) -> None:
        if self._warm is None:
            self._warm = self._pool.submit(warm_streams, self.pipe)

    def submit(self, jobs: list[StreamJob], max_batch: int) -> Future:
        self.start()
        return self._pool.submit(run_stream_jobs, self.pipe, self._streams, jobs)

    def health(self) -> dict:
        ready = self._warm is not None and self._warm.done() and self._warm.exception() is None
        return {"state": "ready" if ready else "starting", "open": len(self._streams)}

    def close(self) -> None:
        if self._own:
            self._pool.shutdown(wait=False, cancel_futures=True)


def _stream_child_main(conn, spec, beat=None) -> None:
    """The stream worker process: windows of the open streams (their state lives here), until told to stop."""
    streams: dict = {}
    child_loop(conn, spec, "stream worker", warm_streams,
               lambda pipe, message: run_stream_jobs(pipe, streams, message[0]), beat)


class StreamProcessWorker(ProcessWorker):
    """The batch worker's supervision (started, restarted after it dies, 503 while down) around a process
    that makes stream windows; the streams open when it dies end with an error."""

    child_main = staticmethod(_stream_child_main)
    process_name = "smf-stream"


class FrameBuffer:
    """The frames of one stream made but not sent yet: frames ``sent`` .. ``made - 1``, each with the prompt
    index of its window. Frames sent are the client's; those not sent yet can be cut (a new prompt)."""

    def __init__(self):
        self.sent = 0
        self.made = 0
        self._joints: list[np.ndarray] = []  # one (J, 3) array per frame not sent
        self._contacts: list[np.ndarray] = []  # and its planted feet (4,)
        self._index: list[int] = []

    def __len__(self) -> int:
        return self.made - self.sent

    def add(self, start: int, joints: np.ndarray, index: int, contacts: np.ndarray | None = None) -> None:
        """Frames ``start`` .. of a window (``start`` must be the next frame: ``made``), with their planted feet
        ``contacts`` (n, 4) (None: none planted)."""
        if start != self.made:
            raise ServeError(500, f"the stream went out of step (frame {start} came, {self.made} was next); "
                                  "start a new one")
        self._joints.extend(joints)
        self._contacts.extend(np.zeros((len(joints), 4), bool) if contacts is None else contacts)
        self._index.extend([index] * len(joints))
        self.made += len(joints)

    def cut(self, frame: int) -> int:
        """Forget the frames from ``frame`` on (``sent`` .. ``made``); returns how many."""
        if not self.sent <= frame <= self.made:
            raise ValueError(f"frames {self.sent} .. {self.made} can be cut, not {frame}")
        drop = self.made - frame
        del self._joints[frame - self.sent:], self._contacts[frame - self.sent:], self._index[frame - self.sent:]
        self.made = frame
        return drop

    def take(self, upto: int) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
        """Frames ``sent`` .. ``upto - 1`` (those made), now sent: (start, prompt index, joints (n, J, 3), contacts
        (n, 4)), one per run of frames of one prompt index."""
        n = max(0, min(upto, self.made) - self.sent)
        out = []
        while n:
            k = 1
            while k < n and self._index[k] == self._index[0]:
                k += 1
            out.append((self.sent, self._index[0], np.stack(self._joints[:k]), np.stack(self._contacts[:k])))
            del self._joints[:k], self._contacts[:k], self._index[:k]
            self.sent += k
            n -= k
        return out


def due_frames(elapsed: float, fps: float, lead: float = STREAM_SEND_LEAD_S) -> int:
    """Frames that may be sent ``elapsed`` s after the play clock started: those that end playing within
    ``lead`` (frame f plays from f / fps to (f + 1) / fps)."""
    return max(0, math.floor((elapsed + lead) * fps + 1e-6))


def cut_frame(sent: int, elapsed: float, fps: float, window_s: float) -> int:
    """Where a new prompt's frames start, ``elapsed`` s after the play clock started: after the frames sent, and
    no sooner than STREAM_SWITCH_FACTOR times ``window_s`` (the slowest recent window of the stream: the window
    with the new prompt is back before its frames play) nor than STREAM_SEND_LEAD_S ahead."""
    ahead = max(STREAM_SEND_LEAD_S, STREAM_SWITCH_FACTOR * window_s)
    return max(sent, math.ceil((elapsed + ahead) * fps - 1e-6))


class StreamHub:
    """The event loop's side of the stream worker: stream slots (at most ``max_streams``) and one gathering
    task that sends every window asked for meanwhile (and the ends of closed streams) as one worker call."""

    def __init__(self, worker, max_streams: int = MAX_STREAMS):
        self.worker, self.max_streams = worker, max_streams
        self.active: set[int] = set()
        self.windows = 0  # windows made, all streams
        self.cut_frames = 0  # frames made and cut before they were sent (new prompts), all streams
        self.sessions: set = set()  # the open streams' sessions: asked to join each call as it starts
        self.inviting = False  # a call is gathering its windows
        self.batches: deque[int] = deque(maxlen=1000)  # windows per worker call (recent calls)
        self.call_s: deque[float] = deque(maxlen=1000)  # wall time of those calls
        self._next_sid = 0
        self._queue: asyncio.Queue | None = None
        self._task: asyncio.Task | None = None

    def open(self) -> int | None:
        """A new stream's id, or None at the limit."""
        if len(self.active) >= self.max_streams:
            return None
        self._next_sid += 1
        self.active.add(self._next_sid)
        return self._next_sid

    def close(self, sid: int) -> None:
        """End stream ``sid``: the worker drops its state in its next call."""
        if sid in self.active:
            self.active.discard(sid)
            self._put(StreamJob(sid, close=True), None)

    def _put(self, job: StreamJob, future) -> None:
        if self._task is None or self._task.done():
            self._queue = asyncio.Queue()
            self._task = asyncio.get_running_loop().create_task(self._run())
        self._queue.put_nowait((job, future))

    def health(self) -> dict:
        calls = sorted(self.call_s)
        return {**self.worker.health(), "active": len(self.active), "max": self.max_streams, "windows": self.windows,
                "cut_frames": self.cut_frames, "recent_calls": len(calls),
                "call_ms_median": round(1000 * calls[len(calls) // 2]) if calls else None,
                "call_ms_max": round(1000 * calls[-1]) if calls else None,
                "windows_per_call": round(sum(self.batches) / len(self.batches), 2) if self.batches else None}

    async def window(self, job: StreamJob):
        """The outcome of one window (StreamFrames or Failure)."""
        future = asyncio.get_running_loop().create_future()
        self._put(job, future)
        return await future

    async def _run(self) -> None:
        while True:
            items = [await self._queue.get()]
            self.inviting = True  # the other streams asking on the same tick, or joining early
            for session in self.sessions:
                session.wake.set()
            await asyncio.sleep(STREAM_GATHER_S)
            self.inviting = False
            while not self._queue.empty():
                items.append(self._queue.get_nowait())
            # a window whose stream has ended meanwhile (its client left: the window's future cancelled, or the
            # stream closed) is not made; closes always go through
            items = [(j, f) for j, f in items
                     if j.close or (f is not None and not f.done() and j.sid in self.active)]
            if not items:
                continue
            jobs = [j for j, _ in items]
            began = _now()
            try:
                outcomes = await asyncio.wrap_future(self.worker.submit(jobs, len(jobs)))
            except ServeError as e:
                outcomes = [Failure(e.status, e.message)] * len(jobs)
            except Exception as e:  # noqa: BLE001 - never leave a stream waiting
                log_event(logging.ERROR, "the stream worker call failed: %s: %s", type(e).__name__, e)
                outcomes = [Failure(500, f"generation failed ({type(e).__name__})")] * len(jobs)
            windows = sum(not j.close for j in jobs)
            self.windows += windows
            if windows:
                self.batches.append(windows)
                self.call_s.append(_now() - began)
            for (_, future), outcome in zip(items, outcomes):
                if future is not None and not future.done():
                    future.set_result(outcome)

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()


class StreamSession:
    """One WebSocket connection's stream: a reader task takes the client's messages; :meth:`play` has the
    windows made ahead (one at a time) and sends their frames, paced by the clock."""

    def __init__(self, ws, hub: StreamHub, sid: int, fps: float):
        self.ws, self.hub, self.sid, self.fps = ws, hub, sid, fps
        self.pending: StreamJob | None = None  # the latest prompt not yet used
        self.pending_index = -1
        self.prompts = 0  # prompt messages so far (the next one's prompt_index)
        self.index = -1  # the prompt_index of the frames being made
        self.stopped = False  # the client said stop, or left
        self.buffer = FrameBuffer()  # the frames made and not sent
        self.start: float | None = None  # the play clock: when frame 0 was sent (monotonic)
        self.wake = asyncio.Event()
        self._send_lock = asyncio.Lock()
        self._recent: deque[float] = deque()
        self._window_s: deque[float] = deque(maxlen=STREAM_RECENT_WINDOWS)  # wall time of recent windows

    async def send(self, message: dict) -> None:
        async with self._send_lock:
            await self.ws.send_text(json.dumps(message, separators=(",", ":")))

    async def error(self, message: str) -> None:
        await self.send({"type": "error", "error": " ".join(str(message).split("\n"))})

    async def read(self) -> None:
        """The client's messages until it leaves or stops: prompts become pending, bad ones get an error."""
        while not self.stopped:
            message = await self.ws.receive()
            if message["type"] == "websocket.disconnect":
                break
            try:
                self._take(message)
            except ServeError as e:
                try:
                    await self.error(e.message)
                except Exception:  # noqa: BLE001 - the client is gone
                    break
        self.stopped = True
        self.wake.set()

    def _take(self, message: dict) -> None:
        now = _now()
        self._recent.append(now)
        while self._recent and self._recent[0] < now - STREAM_MESSAGE_WINDOW_S:
            self._recent.popleft()
        if len(self._recent) > MAX_STREAM_MESSAGES:
            raise ServeError(429, f"more than {MAX_STREAM_MESSAGES} messages in {STREAM_MESSAGE_WINDOW_S:g} s; "
                                  "this one was ignored")
        data = message.get("text")
        if data is None:
            raise ServeError(422, "messages are JSON text, not binary")
        body = parse_body(data.encode("utf-8", "surrogatepass"), StreamMessage)
        if body.stop is not None:
            if body.stop is not True or body.prompt is not None:
                raise ServeError(422, 'stop: send {"stop": true} alone')
            self.stopped = True
            self.wake.set()
            return
        if body.prompt is None:
            raise ServeError(422, 'prompt: a message is {"prompt": "...", "seed"?, "guidance"?} or {"stop": true}')
        prompt = check_prompt(body.prompt, "prompt")
        checked(limits.check_seed, body.seed)
        checked(limits.check_guidance, body.guidance)
        self.pending = StreamJob(self.sid, prompt, body.seed, body.guidance)
        self.pending_index = self.prompts
        self.prompts += 1
        self.wake.set()

    async def _sleep(self, seconds: float | None) -> None:
        """Sleep up to ``seconds`` (None: no limit) or until woken (a message, a stop, a window made): the caller
        clears ``wake`` before it looks at what it waits for."""
        if self.stopped or (seconds is not None and seconds <= 0):
            return
        try:
            await asyncio.wait_for(self.wake.wait(), seconds)
        except asyncio.TimeoutError:
            pass

    def _next_job(self, now: float) -> StreamJob | None:
        """The window to ask for now, if any: a new prompt's (the frames not sent beyond its cut are dropped),
        else one more while the frames made play less than STREAM_AHEAD_S ahead (or STREAM_AHEAD_S +
        STREAM_JOIN_S while the worker's next call gathers windows: a batch)."""
        buf = self.buffer
        if self.pending is not None:
            job, self.pending, self.index = self.pending, None, self.pending_index
            if self.start is None:  # the first window (the play clock starts with its frames)
                return replace(job, new=True)
            frame = cut_frame(buf.sent, now - self.start, self.fps, max(self._window_s, default=0.0))
            if frame < buf.made:
                self.hub.cut_frames += buf.cut(frame)
                job = replace(job, cut=frame)
            return job
        if self.start is None or buf.made >= MAX_STREAM_SECONDS * self.fps:
            return None
        ahead = buf.made / self.fps - (now - self.start)
        # (at the wake time play() computes, ahead is STREAM_AHEAD_S up to rounding: a microsecond's grace, or
        # the loop would wake at once again until the clock moved on)
        if ahead < STREAM_AHEAD_S + 1e-6 or (self.hub.inviting and ahead < STREAM_AHEAD_S + STREAM_JOIN_S):
            return StreamJob(self.sid)
        return None

    async def play(self) -> None:
        """Wait for the first prompt, then make windows ahead and send their frames, until the client stops or
        leaves (or the stream reaches MAX_STREAM_SECONDS)."""
        deadline = _now() + STREAM_START_TIMEOUT_S
        while self.pending is None and not self.stopped:
            if _now() > deadline:
                await self.error(f"no prompt within {STREAM_START_TIMEOUT_S:g} s of connecting; closing")
                return
            self.wake.clear()
            await self._sleep(deadline - _now())
        buf, fps = self.buffer, self.fps
        window: tuple[asyncio.Future, float, int] | None = None  # the window asked for: (outcome, when, index)
        try:
            while not self.stopped:
                self.wake.clear()
                now = _now()
                if window is not None and window[0].done():  # 1. a window made: its frames wait to be sent
                    outcome, asked, index = window[0].result(), window[1], window[2]
                    window = None
                    if not isinstance(outcome, Failure):
                        self._window_s.append(now - asked)
                        try:
                            buf.add(outcome.start, outcome.joints, index, outcome.contacts)
                        except ServeError as e:
                            outcome = Failure(e.status, e.message)
                    if isinstance(outcome, Failure):
                        await self.error(outcome.message)
                        await self.ws.close(SERVER_ERROR)
                        return
                    if self.start is None:
                        self.start = now
                if self.start is not None:  # 2. send the frames due: at most STREAM_SEND_LEAD_S ahead
                    for first, index, joints, planted in buf.take(due_frames(now - self.start, fps)):
                        await self.send({"type": "frames", "start": first, "fps": fps, "prompt_index": index,
                                         "joints": np.round(joints.astype(np.float64), STREAM_DECIMALS).tolist(),
                                         "contacts": planted.T.astype(int).tolist()})
                    if buf.sent >= MAX_STREAM_SECONDS * fps:
                        await self.error(f"a stream lasts at most {MAX_STREAM_SECONDS:g} s; start a new one")
                        return
                    now = _now()
                if window is None:  # 3. the next window: one at a time
                    job = self._next_job(now)
                    if job is not None:
                        future = asyncio.ensure_future(self.hub.window(job))
                        future.add_done_callback(lambda _: self.wake.set())
                        window = (future, now, self.index)
                wake = []  # 4. sleep until a message is due, a window is wanted or made, or the client speaks
                if self.start is not None and len(buf):
                    wake.append(self.start + min(buf.sent + STREAM_MESSAGE_FRAMES, buf.made) / fps - STREAM_SEND_LEAD_S)
                if self.start is not None and window is None and buf.made < MAX_STREAM_SECONDS * fps:
                    wake.append(self.start + buf.made / fps - STREAM_AHEAD_S)
                await self._sleep(min(wake) - _now() if wake else None)
        finally:
            if window is not None:
                window[0].cancel()


async def serve_stream(ws, hub: StreamHub, fps: float) -> None:
    """One connection: a stream slot (or an error and close at the limit), the reader and the player; the
    stream's state is dropped when the client stops or leaves."""
    await ws.accept()
    sid = hub.open()
    if sid is None:
        why = (f"the server is at its limit of {hub.max_streams} live streams; try again later" if hub.max_streams
               else "this server has live streams off")
        await ws.send_text(json.dumps({"type": "error", "error": why}))
        await ws.close(TRY_LATER)
        return
    session = StreamSession(ws, hub, sid, fps)
    hub.sessions.add(session)
    reader = asyncio.ensure_future(session.read())
    try:
        await session.play()
    except Exception as e:  # noqa: BLE001 - a client gone mid-send, or a bug: end this stream only
        if type(e).__name__ not in ("WebSocketDisconnect", "ClientDisconnected", "ConnectionClosed"):
            log_event(logging.ERROR, "stream %s failed: %s: %s", sid, type(e).__name__, e)
    finally:
        session.stopped = True
        reader.cancel()
        hub.sessions.discard(session)
        hub.close(sid)
        try:
            await ws.close()
        except Exception:  # noqa: BLE001 - already closed
            pass


__all__ = ["MAX_STREAM_MESSAGE_BYTES", "FrameBuffer", "StreamHub", "StreamJob", "StreamMessage", "StreamProcessWorker",
           "ThreadStreamWorker", "cut_frame", "due_frames", "run_stream_jobs", "serve_stream"]
