"""A live stream's pacing (serve/live.py) on its own: the frame buffer, the send and cut rules, and one
connection's session driven by a fake WebSocket and a fake stream worker (a window takes 50 ms), on a virtual
clock (serve_helpers.VirtualClockLoop: no wall clock, no real waiting): frames sent never beyond the send lead, the
frames made and not sent bounded, a new prompt cut in."""

from __future__ import annotations

import asyncio
import json

import numpy as np
import pytest

from stablemofusion.pipelines.stream import STREAM_CHUNK, STREAM_REWIND
from stablemofusion.serve.http_errors import ServeError
from stablemofusion.serve.server_limits import (STREAM_AHEAD_S, STREAM_JOIN_S, STREAM_MESSAGE_FRAMES,
                                                STREAM_SEND_LEAD_S, STREAM_SWITCH_FACTOR)
from stablemofusion.serve.live import FrameBuffer, StreamFrames, StreamSession, cut_frame, due_frames

from serve_helpers import run_virtual

FPS = 20


def chunk(start: int, n: int, tag: float) -> np.ndarray:
    """Joints whose every coordinate is the frame number plus ``tag``."""
    return np.broadcast_to((np.arange(start, start + n) + tag)[:, None, None], (n, 22, 3)).astype(np.float32)


def test_the_frame_buffer_sends_in_order_cuts_what_is_not_sent_and_splits_by_prompt():
    buf = FrameBuffer()
    buf.add(0, chunk(0, 12, 0), 0)
    buf.add(12, chunk(12, 12, 0), 0)
    with pytest.raises(ServeError):
        buf.add(30, chunk(30, 12, 0), 0)  # out of step
    assert buf.take(5)[0][:2] == (0, 0) and buf.sent == 5 and len(buf) == 19
    with pytest.raises(ValueError):
        buf.cut(4)  # sent: the client's
    assert buf.cut(9) == 15 and buf.made == 9
    buf.add(9, chunk(9, 12, 0.5), 1)
    out = buf.take(100)
    assert [(s, i, len(j), len(c)) for s, i, j, c in out] == [(5, 0, 4, 4), (9, 1, 12, 12)]
    assert np.array_equal(out[0][2][:, 0, 0], [5, 6, 7, 8]) and out[1][2][0, 0, 0] == 9.5
    assert buf.sent == buf.made == 21 and buf.take(100) == []


def test_the_send_and_cut_rules():
    assert due_frames(0.0, FPS) == round(STREAM_SEND_LEAD_S * FPS)  # frames ending within the lead
    assert due_frames(1.0, FPS, lead=0.3) == 26 and due_frames(-5.0, FPS) == 0
    # a new prompt starts after the frames sent, and far enough ahead for its window
    assert cut_frame(sent=30, elapsed=1.0, fps=FPS, window_s=0.0) == 30
    assert cut_frame(sent=0, elapsed=1.0, fps=FPS, window_s=0.0) == round((1.0 + STREAM_SEND_LEAD_S) * FPS)
    assert cut_frame(sent=0, elapsed=1.0, fps=FPS, window_s=0.4) == round((1.0 + STREAM_SWITCH_FACTOR * 0.4) * FPS)


def test_a_cut_never_reaches_back_further_than_a_stream_remembers():
    """The frames made and not sent (what a new prompt may cut) are at most the lead made ahead (joining a
    call early included) plus a window, within the frames a stream can be cut back (STREAM_REWIND)."""
    assert (STREAM_AHEAD_S + STREAM_JOIN_S) * FPS + STREAM_CHUNK <= STREAM_REWIND


class FakeWebSocket:
    def __init__(self):
        self.incoming: asyncio.Queue = asyncio.Queue()
        self.sent: list[tuple[float, dict]] = []
        self.session: StreamSession | None = None
        self.unsent: list[int] = []  # frames made and not sent, at every message

    async def send_text(self, text: str) -> None:
        m = json.loads(text)
        self.sent.append((asyncio.get_running_loop().time() - self.session.start, m))
        self.unsent.append(len(self.session.buffer))

    async def receive(self) -> dict:
        return await self.incoming.get()

    async def close(self, code: int = 1000) -> None:
        pass


class FakeHub:
    """One stream's windows: 12 frames, 50 ms each; a frame's joints are its number plus 0.1 times the
    number of prompts used so far (so a frame made again after a cut differs)."""

    def __init__(self):
        self.cut_frames, self.made, self.prompts, self.inviting = 0, 0, 0, False
        self.jobs: list[tuple[float, object, int]] = []  # (time, job, frames sent then)
        self.session: StreamSession | None = None

    async def window(self, job):
        self.jobs.append((asyncio.get_running_loop().time(), job, self.session.buffer.sent))
        if job.cut is not None:
            assert job.cut >= self.session.buffer.sent and job.cut <= self.made
            self.made = job.cut
        self.prompts += job.prompt is not None
        await asyncio.sleep(0.05)
        start, self.made = self.made, self.made + STREAM_CHUNK
        return StreamFrames(start, chunk(start, STREAM_CHUNK, 0.1 * self.prompts))


def test_a_session_sends_frames_within_the_send_lead_keeps_the_buffer_bounded_and_cuts_for_a_new_prompt():
    async def run():
        ws, hub = FakeWebSocket(), FakeHub()
        session = StreamSession(ws, hub, 1, FPS)
        ws.session = hub.session = session
        reader = asyncio.ensure_future(session.read())
        player = asyncio.ensure_future(session.play())
        await ws.incoming.put({"type": "websocket.receive", "text": json.dumps({"prompt": "a person walks"})})
        await asyncio.sleep(2.5)
        prompted = asyncio.get_running_loop().time() - session.start
        await ws.incoming.put({"type": "websocket.receive", "text": json.dumps({"prompt": "a person waves"})})
        await asyncio.sleep(2.0)
        await ws.incoming.put({"type": "websocket.receive", "text": json.dumps({"stop": True})})
        await asyncio.wait_for(player, 5)
        reader.cancel()
        return ws, hub, prompted

    ws, hub, prompted = run_virtual(run())
    messages = [m for _, m in ws.sent]
    assert all(m["type"] == "frames" for m in messages)
    # never sent beyond the send lead (on the server's own play clock), and a few frames a message
    assert all((m["start"] + len(m["joints"])) / FPS <= t + STREAM_SEND_LEAD_S + 1e-6 for t, m in ws.sent)
    assert max(len(m["joints"]) for m in messages[1:]) <= STREAM_MESSAGE_FRAMES + 1
    # frames made ahead (not sent) bounded by the lead made ahead and one window
    assert max(ws.unsent) <= STREAM_AHEAD_S * FPS + STREAM_CHUNK
    assert max(ws.unsent) >= (STREAM_AHEAD_S - STREAM_SEND_LEAD_S) * FPS  # and they are made ahead
    # contiguous; the new prompt's frames from the cut on, made again after it (their joints tell)
    joints = np.concatenate([np.array(m["joints"]) for m in messages])[:, 0, 0]
    index = np.concatenate([[m["prompt_index"]] * len(m["joints"]) for m in messages])
    assert all(b["start"] == a["start"] + len(a["joints"]) for a, b in zip(messages, messages[1:]))
    cuts = [(t, job, sent) for t, job, sent in hub.jobs if job.cut is not None]
    assert len(cuts) == 1 and hub.cut_frames > 0
    _, job, sent = cuts[0]
    assert job.prompt == "a person waves" and not job.new and hub.jobs[0][1].new
    assert np.array_equal(index, np.arange(len(index)) >= job.cut)
    assert np.allclose(joints, np.arange(len(joints)) + np.where(index == 1, 0.2, 0.1))
    # the cut: after the frames sent, and about the send lead (or the slowest window, 50 ms, x the factor) ahead
    assert job.cut >= sent and (job.cut / FPS - prompted) <= STREAM_SEND_LEAD_S + 0.2


class FakeWorker:
    """The stream worker's interface: every call takes 0.1 s (of the loop's clock); windows as FakeHub's."""

    def __init__(self):
        self.made: dict[int, int] = {}
        self.calls: list[list] = []

    def submit(self, jobs, max_batch):
        from concurrent.futures import Future

        done = Future()
        asyncio.get_running_loop().call_later(0.1, lambda: done.set_result(self._run(jobs)))
        return done

    def _run(self, jobs):
        self.calls.append(jobs)
        out = []
        for job in jobs:
            if job.close:
                out.append(None)
                continue
            start = job.cut if job.cut is not None else self.made.get(job.sid, 0)
            self.made[job.sid] = start + STREAM_CHUNK
            out.append(StreamFrames(start, chunk(start, STREAM_CHUNK, 0)))
        return out

    def health(self):
        return {}


def test_streams_join_the_worker_call_that_starts_so_their_windows_are_batched():
    """Two streams started 0.3 s apart: without joining, each would ask on its own phase (one window a call);
    a stream with less than STREAM_AHEAD_S + STREAM_JOIN_S made ahead joins the other's call."""
    from stablemofusion.serve.live import StreamHub, serve_stream

    class Socket(FakeWebSocket):
        async def accept(self):
            pass

        async def send_text(self, text: str) -> None:
            self.sent.append((asyncio.get_running_loop().time(), json.loads(text)))

    async def run(worker):
        hub = StreamHub(worker, max_streams=2)
        sockets = [Socket(), Socket()]
        tasks = []
        for ws in sockets:
            tasks.append(asyncio.ensure_future(serve_stream(ws, hub, FPS)))
            await ws.incoming.put({"type": "websocket.receive", "text": json.dumps({"prompt": "a person walks"})})
            await asyncio.sleep(0.3)
        await asyncio.sleep(4.0)
        for ws in sockets:
            await ws.incoming.put({"type": "websocket.receive", "text": json.dumps({"stop": True})})
        await asyncio.wait_for(asyncio.gather(*tasks), 5)
        hub.stop()
        return sockets

    worker = FakeWorker()
    sockets = run_virtual(run(worker))
    windows = [sum(not j.close for j in jobs) for jobs in worker.calls]
    later = windows[len(windows) // 2:]  # once both streams run (each first fills its lead alone)
    assert sum(w == 2 for w in later) >= 0.8 * len(later), str(windows)
    for ws in sockets:  # and each stream still gets its frames in order, none lost
        messages = [m for _, m in ws.sent]
        assert messages[0]["start"] == 0
        assert all(b["start"] == a["start"] + len(a["joints"]) for a, b in zip(messages, messages[1:]))
