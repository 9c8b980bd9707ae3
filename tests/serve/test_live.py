"""Live streams: the generator API (pipe.stream) and the WebSocket /v1/stream of `smf serve` on a tiny
random-weight checkpoint, served by uvicorn on a free 127.0.0.1 port (as `smf serve` configures it)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from stablemofusion.core.errors import SMFError
from stablemofusion.motion.features import joints_from_features
from stablemofusion.serve import create_app
from stablemofusion.serve.server_limits import STREAM_AHEAD_S, STREAM_SEND_LEAD_S

from serve_helpers import live_server

ws_client = pytest.importorskip("websockets.sync.client")
from websockets.exceptions import ConnectionClosed, InvalidStatus  # noqa: E402


def test_the_generator_api_makes_contiguous_chunks_that_follow_the_prompt(pipe):
    s = pipe.stream("a person walks forward", seed=3)
    chunks = [next(s), next(s), s.send("a person waves both hands"), next(s)]
    assert [c.start for c in chunks] == [0, 12, 24, 36]
    assert [c.prompt_index for c in chunks] == [0, 0, 1, 1]
    assert [c.prompt for c in chunks][2] == "a person waves both hands"
    assert all(c.joints.shape == (12, 22, 3) and np.isfinite(c.joints).all() for c in chunks)
    again = pipe.stream("a person walks forward", seed=3)
    assert np.allclose(next(again).joints, chunks[0].joints)  # window j uses seed + j
    with pytest.raises(SMFError):
        s.set_prompt("  ")
    with pytest.raises(SMFError):
        pipe.stream("a person walks", sampler="ddpm")


def test_the_stream_continues_where_the_character_stands(pipe):
    """Each window is placed where the motion so far leaves the body: the chunks' joints are exactly the joints
    of the whole motion decoded at once (position and heading carried over), and no step at a switch is
    larger than the steps inside the chunks."""
    s = pipe.stream("a person walks forward", seed=0)
    chunks = [s.send(p) for p in [None, None, "a person runs", None, "a person jumps", None, None]]
    joints = np.concatenate([c.joints for c in chunks])
    whole = joints_from_features(np.concatenate([c.features for c in chunks]).astype(np.float64), pipe.skeleton)
    assert np.abs(joints - whole).max() < 1e-3
    steps = np.linalg.norm(np.diff(joints, axis=0), axis=-1).max(-1)  # largest joint step per frame
    seams = np.array([c.start - 1 for c in chunks[1:]])
    inside = np.delete(steps, seams)
    assert steps[seams].max() <= inside.max()


def test_a_cut_back_to_a_window_start_is_the_stream_that_never_made_the_dropped_frames(pipe):
    """Rolling back (what the server does with frames it has not sent when a new prompt arrives): cut at a
    window's start, the next chunk is exactly the chunk of a stream that switched prompt there, same seed."""
    a = pipe.stream("a person walks forward", seed=5)
    made = [next(a) for _ in range(4)]  # frames 0 .. 47
    assert a.cut(24) == 24 and a.frames == 24 and a.windows == 2
    after = a.send("a person waves both hands")
    b = pipe.stream("a person walks forward", seed=5)
    kept = [next(b), next(b)]
    switched = b.send("a person waves both hands")
    assert after.start == 24 and after.prompt_index == 1 and after.prompt == "a person waves both hands"
    assert np.array_equal(after.joints, switched.joints) and np.array_equal(after.features, switched.features)
    assert all(np.array_equal(m.joints, k.joints) for m, k in zip(made, kept))
    assert not np.allclose(after.joints, made[2].joints)  # the new prompt, not the frames that were cut
    assert [c.start for c in (next(a), next(b))] == [36, 36]


def test_a_cut_mid_window_joins_the_kept_frames_exactly(pipe):
    """Cut inside a chunk: the frames kept plus the frames made after the cut are one motion: its joints are
    those of its features decoded at once (the world heading and position restored to the cut), and the step
    at the cut is no larger than the steps inside."""
    s = pipe.stream("a person walks forward", seed=1)
    made = [next(s) for _ in range(5)]  # frames 0 .. 59
    s.cut(41)
    s.set_prompt("a person runs")
    new = [next(s), next(s)]
    assert [c.start for c in new] == [41, 53] and all(c.prompt_index == 1 for c in new)
    joints = np.concatenate([c.joints for c in made])[:41]
    features = np.concatenate([c.features for c in made])[:41]
    joints = np.concatenate([joints] + [c.joints for c in new])
    features = np.concatenate([features] + [c.features for c in new])
    whole = joints_from_features(features.astype(np.float64), pipe.skeleton)
    assert np.abs(joints - whole).max() < 1e-3
    steps = np.linalg.norm(np.diff(joints, axis=0), axis=-1).max(-1)
    assert steps[40] <= np.delete(steps, [40, 52]).max()
    again = [next(s) for _ in range(6)]  # and it goes on (frames 65 .. 136): cut back to any of the last 60
    assert s.earliest_cut == s.frames - 60
    with pytest.raises(SMFError):
        s.cut(s.frames - 61)
    with pytest.raises(SMFError):
        s.cut(s.frames + 1)
    assert s.cut(s.frames - 60) == 60 and next(s).start == again[-1].start + 12 - 60


def test_a_cut_back_to_frame_0_restarts_the_stream(pipe):
    s = pipe.stream("a person walks forward", seed=2)
    first = next(s)
    next(s)
    s.cut(0)
    assert s.frames == 0 and s.windows == 0 and np.array_equal(next(s).joints, first.joints)


@pytest.fixture(scope="module")
def live(pipe):
    app = create_app(pipe, max_streams=2)
    with live_server(app) as url:
        yield app, url.replace("http://", "ws://") + "/v1/stream"


@pytest.fixture
def server(live):
    """The live server with no stream open (those of the test before have ended)."""
    idle(live[0].state.streams)
    return live


def idle(hub, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while hub.active and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not hub.active


def frames(ws, n: int, timeout: float = 30.0) -> list[dict]:
    """The next frames messages, until they hold ``n`` frames or more (error messages are skipped)."""
    out = []
    while sum(len(m["joints"]) for m in out) < n:
        m = json.loads(ws.recv(timeout=timeout))
        if m["type"] == "frames":
            out.append(m)
    return out


def contiguous(messages: list[dict]) -> bool:
    return all(b["start"] == a["start"] + len(a["joints"]) for a, b in zip(messages, messages[1:]))


def test_protocol_frames_prompt_index_errors_and_stop(server):
    app, url = server
    with ws_client.connect(url, open_timeout=10) as ws:
        ws.send(json.dumps({"prompt": "a person walks forward", "seed": 1}))
        first = frames(ws, 24)
        assert first[0]["start"] == 0 and contiguous(first) and first[0]["fps"] == 20
        assert first[0]["prompt_index"] == 0 and np.array(first[0]["joints"]).shape[1:] == (22, 3)
        for bad, why in [("not json", "not valid JSON"), (json.dumps({"prompt": "x", "bogus": 1}), "bogus"),
                         (json.dumps({"prompt": ""}), "prompt must be a non-empty text"), (json.dumps({"seed": 2}), "prompt"),
                         (json.dumps({"stop": False}), "stop"), (json.dumps([1]), "")]:
            ws.send(bad)
            m = json.loads(ws.recv(timeout=30))
            while m["type"] == "frames":
                first.append(m)
                m = json.loads(ws.recv(timeout=30))
            assert m["type"] == "error" and why in m["error"]
        ws.send(json.dumps({"prompt": "a person waves both hands", "guidance": 3.0}))
        got = frames(ws, 72)
        assert contiguous(first + got)  # nothing lost to the errors
        assert [m["prompt_index"] for m in got][-1] == 1  # bad messages are not prompts
        ws.send(json.dumps({"stop": True}))
        with pytest.raises(ConnectionClosed) as closed:
            while True:
                ws.recv(timeout=10)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1000


def test_a_connection_beyond_the_limit_gets_a_clear_error(server):
    app, url = server
    with ws_client.connect(url) as a, ws_client.connect(url) as b:
        for ws in (a, b):
            ws.send(json.dumps({"prompt": "a person walks", "seed": 0}))
            frames(ws, 1)
        with ws_client.connect(url) as c:
            m = json.loads(c.recv(timeout=10))
            assert m["type"] == "error" and "limit of 2 live streams" in m["error"]
            with pytest.raises(ConnectionClosed) as closed:
                c.recv(timeout=10)
            assert closed.value.rcvd.code == 1013


def test_a_client_that_leaves_ends_its_stream_and_its_work(server):
    app, url = server
    hub = app.state.streams
    ws = ws_client.connect(url)
    ws.send(json.dumps({"prompt": "a person walks", "seed": 0}))
    frames(ws, 2)
    ws.close()
    idle(hub)
    # the worker drops the stream's state in the call after the one in flight (calls run one after another), so
    # once it has, no window of the stream is being made, however busy the machine
    deadline = time.monotonic() + 60
    while hub.health()["open"] and time.monotonic() < deadline:
        time.sleep(0.05)
    assert hub.health()["open"] == 0
    made = hub.windows
    time.sleep(1.5)
    assert hub.windows == made  # no window is made for a stream whose client has gone


def test_frames_are_paced_never_more_than_the_send_lead_ahead_and_a_new_prompt_cuts_the_rest(server):
    """Frames are made up to STREAM_AHEAD_S ahead but sent at most STREAM_SEND_LEAD_S ahead of play time; a new
    prompt drops the frames made and not sent beyond its cut, so it shows well before the frames made ahead
    would have played, and the frames stay contiguous."""
    app, url = server
    hub = app.state.streams
    cut_before = hub.cut_frames
    with ws_client.connect(url) as ws:
        ws.send(json.dumps({"prompt": "a person walks", "seed": 0}))
        t0, ahead, got, sent = None, [], [], None
        while sum(len(m["joints"]) for m in got) < 160:
            m = frames(ws, 1)[0]
            now = time.monotonic()
            t0 = now if t0 is None else t0
            got.append(m)
            ahead.append((m["start"] + len(m["joints"])) / m["fps"] - (now - t0))  # its end ahead of play
            if sent is None and m["start"] >= 80:
                assert hub.health()["active"] == 1
                sent = time.monotonic()
                ws.send(json.dumps({"prompt": "a person waves both hands"}))
    assert max(ahead) <= STREAM_SEND_LEAD_S + 0.1  # the server's bound (its clock starts a moment before ours)
    received = sum(len(m["joints"]) for m in got)
    assert received / 20 - (now - t0) < STREAM_SEND_LEAD_S + 0.1  # 8 s of motion took 8 s less the lead, at least
    assert contiguous(got) and got[0]["start"] == 0
    new = next(m for m in got if m["prompt_index"] == 1)
    assert all(m["prompt_index"] == 0 for m in got if m["start"] < new["start"])
    assert all(m["prompt_index"] == 1 for m in got if m["start"] >= new["start"])
    assert hub.cut_frames > cut_before  # frames made ahead were dropped ...
    assert t0 + new["start"] / 20 - sent < STREAM_AHEAD_S  # ... so the prompt shows before they would have played
    # Whether frames arrive before their play time, and how soon a prompt shows, depend on the CPU and its
    # load: figures of benchmarks/stream_check.py (shipped model, docs/serve.md), not timed assertions here.


def test_a_page_of_another_site_cannot_open_a_stream(server):
    app, url = server
    with pytest.raises(InvalidStatus) as refused:
        ws_client.connect(url, origin="http://evil.example")
    assert refused.value.response.status_code == 403
    with pytest.raises(InvalidStatus):
        ws_client.connect(url, additional_headers={"Host": "evil.example"})
    with ws_client.connect(url, origin=url.replace("ws://", "http://").rsplit("/v1", 1)[0]) as ws:  # our viewer
        ws.send(json.dumps({"prompt": "a person walks", "seed": 0}))
        assert frames(ws, 1)[0]["start"] == 0


def test_a_window_and_the_close_of_its_stream_in_one_call_make_no_window_and_no_error(pipe, caplog):
    """A client that sends a prompt and leaves at once: its window and its close can reach the worker in one
    call; the window is not made (None, like the close), the other streams' windows are, nothing is logged."""
    from stablemofusion.serve.live import StreamFrames, StreamJob, run_stream_jobs

    streams: dict = {}
    opened = run_stream_jobs(pipe, streams, [StreamJob(1, "a person walks", seed=0, new=True),
                                             StreamJob(2, "a person waves", seed=1, new=True)])
    assert all(isinstance(o, StreamFrames) for o in opened) and set(streams) == {1, 2}
    caplog.set_level("WARNING")
    out = run_stream_jobs(pipe, streams, [StreamJob(1), StreamJob(2), StreamJob(1, close=True),
                                          StreamJob(3, "a person bows", seed=2, new=True), StreamJob(3, close=True)])
    assert out[0] is None and out[2] is None and out[3] is None and out[4] is None
    assert isinstance(out[1], StreamFrames) and set(streams) == {2}
    assert [r for r in caplog.records if r.levelname in ("WARNING", "ERROR")] == []


def test_the_hub_makes_no_window_for_a_stream_that_ended_before_its_call():
    """A window asked for and then abandoned (its client left: the future cancelled, the stream closed) before the
    gathering call starts never reaches the worker; the close does."""
    import asyncio
    from concurrent.futures import Future

    from stablemofusion.serve.live import StreamHub, StreamJob

    class Recorder:
        def __init__(self):
            self.calls = []

        def submit(self, jobs, max_batch):
            self.calls.append(list(jobs))
            done = Future()
            done.set_result([None] * len(jobs))
            return done

        def health(self):
            return {}

    async def run(worker):
        hub = StreamHub(worker, max_streams=4)
        gone, stays = hub.open(), hub.open()
        left = asyncio.ensure_future(hub.window(StreamJob(gone, "a person walks", new=True)))
        kept = asyncio.ensure_future(hub.window(StreamJob(stays, "a person waves", new=True)))
        await asyncio.sleep(0)
        left.cancel()
        hub.close(gone)
        await kept
        hub.stop()

    worker = Recorder()
    asyncio.run(run(worker))
    sent = [j for call in worker.calls for j in call]
    assert [(j.sid, j.close) for j in sent] == [(2, False), (1, True)]
