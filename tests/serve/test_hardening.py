"""One test per hole a hostile client found: isolation, strict input, bounded bodies and uploads,
cancelled work, one error format, escaped logs, Host and content-type checks, connection timeouts."""

from __future__ import annotations

import asyncio
import io
import json
import logging
import re
import socket
import threading
import time

import httpx
import numpy as np
import pytest

from stablemofusion.serve import create_app
from stablemofusion.serve.guard import Guard

from serve_helpers import OCTETS, call, live_server

JSON = {"Content-Type": "application/json"}


def post_raw(app, url: str, content: bytes, headers: dict):
    async def go():
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
            return await client.post(url, content=content, headers=headers)
    return asyncio.run(go())


class Poisoned:
    """The tiny pipeline, failing (as the tokenizer did on a lone surrogate) any call with a 'poison' prompt."""

    def __init__(self, pipe):
        self._pipe, self.calls = pipe, []

    def __getattr__(self, name):
        return getattr(self._pipe, name)

    def __call__(self, prompts, **kw):
        self.calls.append(list(prompts))
        if any("poison" in p for p in prompts):
            raise TypeError("TextEncodeInput must be Union[TextInputSequence, ...]")
        return self._pipe(prompts, **kw)


def test_a_failing_request_does_not_fail_its_batch(pipe):
    """Six normal requests and one that breaks the pipeline, in one batch: the six get their motions (as
    alone), the bad one its own 500 JSON."""
    poisoned = Poisoned(pipe)
    app = create_app(poisoned, wait_ms=300)
    reqs = [{"prompt": f"a person walks {k}", "seconds": 2.0, "seed": k, "steps": 1} for k in range(6)]
    reqs.insert(3, {"prompt": "poison", "seconds": 2.0, "seed": 9, "steps": 1})
    out = call(app, *[("POST", "/v1/generate", r) for r in reqs])
    assert app.state.batcher.batch_sizes == [7]
    assert [r.status_code for r in out] == [200, 200, 200, 500, 200, 200, 200]
    assert "generation failed" in out[3].json()["error"]
    for r, req in zip(out, reqs):
        if req["prompt"] != "poison":
            alone = pipe([req["prompt"]], seconds=2.0, seed=[req["seed"]], steps=1)[0]
            assert np.abs(np.asarray(r.json()["joints"]) - alone.joints).max() < 1e-4


def test_a_prompt_that_is_not_valid_text_gets_422(pipe):
    app = create_app(pipe)
    bad = b'{"prompt": "walk \\ud800", "seconds": 2, "steps": 1}'
    r = post_raw(app, "/v1/generate", bad, JSON)
    assert r.status_code == 422 and "not valid text" in r.json()["error"]
    seg = b'{"segments": [{"prompt": "walk", "seconds": 2}, {"prompt": "\\udfff", "seconds": 2}], "steps": 1}'
    r = post_raw(app, "/v1/timeline", seg, JSON)
    assert r.status_code == 422 and "segments.1.prompt" in r.json()["error"]


def test_a_bad_timeline_fails_alone(pipe):
    """A timeline with a 1e-9 s segment sent with two good ones: 422 for it, the others answered."""
    good = {"segments": [{"prompt": "a person walks", "seconds": 2.5}], "seed": 1, "steps": 1}
    bad = {"segments": [{"prompt": "a person walks", "seconds": 2.5}, {"prompt": "waves", "seconds": 1e-9}],
           "steps": 1}
    app = create_app(pipe, wait_ms=300)
    a, b, c = call(app, ("POST", "/v1/timeline", good), ("POST", "/v1/timeline", bad), ("POST", "/v1/timeline", good))
    assert a.status_code == c.status_code == 200 and a.json()["joints"] == c.json()["joints"]
    assert b.status_code == 422 and "segments.1.seconds" in b.json()["error"] and "a person" not in b.json()["error"]


@pytest.mark.parametrize("body, field", [
    ({"prompt": "walk", "seed": True}, "seed"),
    ({"prompt": "walk", "seconds": "4"}, "seconds"),
    ({"prompt": "walk", "steps": 2.0}, "steps"),
    ({"prompt": 5}, "prompt"),
    ({"prompt": "walk", "guidance": "2"}, "guidance"),
])
def test_json_types_are_strict(pipe, body, field):
    (r,) = call(create_app(pipe), ("POST", "/v1/generate", body))
    assert r.status_code == 422 and r.json()["error"].startswith(field)


@pytest.mark.parametrize("content, headers, status", [
    (b'{"prompt": "walk \xff\xfe"}', JSON, 422),  # not UTF-8
    (b'{"prompt": "walk", "seconds": NaN}', JSON, 422),
    (b"[" * 5000 + b"]" * 5000, JSON, 422),
    (b'{"prompt": "walk"}', {"Content-Type": "text/plain"}, 415),  # a cross-site form could send this
])
def test_every_4xx_is_one_error_format(pipe, content, headers, status):
    r = post_raw(create_app(pipe), "/v1/generate", content, headers)
    assert r.status_code == status and set(r.json()) == {"error"} and "\n" not in r.json()["error"]


def test_the_host_header_is_checked(pipe):
    async def go(app, host):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url=f"http://{host}:8000") as client:
            return await client.get("/v1/health")
    for host in ("evil.example", "127.0.0.1.evil.example"):
        r = asyncio.run(go(create_app(pipe), host))
        assert r.status_code == 400 and "Host" in r.json()["error"]
    for host in ("localhost", "127.0.0.1", "[::1]"):
        assert asyncio.run(go(create_app(pipe), host)).status_code != 400
    assert asyncio.run(go(create_app(pipe, allowed_hosts=("motion.lan",)), "motion.lan")).status_code != 400


def test_convert_needs_octet_stream_or_our_header(pipe):
    from stablemofusion.motion.files import load_motion

    buf = io.BytesIO()
    np.save(buf, load_motion("example:wave-both-hands").joints.astype(np.float32))
    app = create_app(pipe)
    for headers in ({"Content-Type": "text/plain"}, {"Content-Type": "multipart/form-data; boundary=x"}, {}):
        r = post_raw(app, "/v1/convert?filename=w.npy", buf.getvalue(), headers)
        assert r.status_code == 415 and "application/octet-stream" in r.json()["error"]
    assert post_raw(app, "/v1/convert?filename=w.npy", buf.getvalue(), {"X-SMF-Client": "1"}).status_code == 200
    assert post_raw(app, "/v1/convert?filename=w.npy", buf.getvalue(), OCTETS).status_code == 200


def run_guard(headers: list, chunks, limit: int = 1000):
    """Drive the Guard alone with a body of ``chunks`` (chunked: no Content-Length); returns (status, chunks
    pulled, whether the inner app ran)."""
    pulled, ran, sent = [0], [False], []

    async def inner(scope, receive, send):
        ran[0] = True
        await receive()

    async def receive():
        pulled[0] += 1
        chunk = next(chunks, None)
        return {"type": "http.request", "body": chunk or b"", "more_body": chunk is not None}

    async def send(message):
        sent.append(message)

    scope = {"type": "http", "method": "POST", "path": "/v1/generate",
             "headers": [(b"host", b"127.0.0.1:8000"), (b"content-type", b"application/json"), *headers]}
    asyncio.run(Guard(inner, max_body_bytes=limit)(scope, receive, send))
    return sent[0]["status"] if sent else None, pulled[0], ran[0]


def test_body_limit_holds_while_reading_a_chunked_body():
    """A chunked body of 64 MB (no Content-Length) is refused after the limit, not read whole."""
    status, pulled, ran = run_guard([(b"transfer-encoding", b"chunked")], iter([b"x" * 65536] * 1000), limit=16384)
    assert status == 413 and pulled == 1 and not ran


def test_content_length_with_chunked_is_refused():
    status, pulled, ran = run_guard([(b"content-length", b"5"), (b"transfer-encoding", b"chunked")],
                                    iter([b"x" * 100]))
    assert status == 400 and pulled == 0 and not ran
    status, _, ran = run_guard([(b"content-length", b"5"), (b"content-length", b"7")], iter([b"x" * 5]))
    assert status == 400 and not ran


def test_log_lines_are_escaped(checkpoint, tmp_path, caplog):
    """A prompt's ANSI escapes and NUL reach the log escaped (the out-of-domain warning quotes the prompt)."""
    import json
    import shutil

    from stablemofusion.data.lexicon import known_actions, load_lexicon
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    folder = tmp_path / "ck"
    shutil.copytree(checkpoint, folder)
    (folder / "actions.json").write_text(json.dumps(known_actions(load_lexicon("bandai"), 0.56)))
    app = create_app(MotionPipeline.from_pretrained(folder, device="cpu"))
    with caplog.at_level(logging.WARNING, logger="stablemofusion.serve"):
        (r,) = call(app, ("POST", "/v1/generate", {"prompt": "does a backflip \x1b[2J\x00", "seconds": 2, "steps": 1}))
    assert r.status_code == 200
    lines = [rec.getMessage() for rec in caplog.records if rec.name == "stablemofusion.serve"]
    assert any("backflip \\x1b[2J\\x00" in line for line in lines)
    assert not any(c in line for line in lines for c in "\x1b\x00")


class Gate:
    """A pipeline whose first call waits for ``release`` (the worker busy); records every prompt it gets."""

    def __init__(self, pipe):
        self._pipe, self.prompts, self.release, self.busy = pipe, [], threading.Event(), threading.Event()

    def __getattr__(self, name):
        return getattr(self._pipe, name)

    def __call__(self, prompts, **kw):
        self.prompts += list(prompts)
        if "block" in prompts[0]:
            self.busy.set()
            self.release.wait(30)
        return self._pipe(prompts, **kw)

    def timeline(self, segments, **kw):
        self.prompts += [p for p, _ in segments]
        return self._pipe.timeline(segments, **kw)


def test_a_job_whose_client_left_is_dropped_before_it_runs(pipe):
    gate = Gate(pipe)
    app = create_app(gate, wait_ms=0)
    with live_server(app) as url:
        with httpx.Client(base_url=url, timeout=30) as client:
            assert client.post("/v1/generate", json={"prompt": "warm", "seconds": 2, "steps": 1}).status_code == 200
        first = threading.Thread(target=lambda: httpx.post(
            url + "/v1/generate", json={"prompt": "block", "seconds": 2, "steps": 1}, timeout=30))
        first.start()
        assert gate.busy.wait(10)
        gave_up = []

        def leave(k: int) -> None:  # a client that gives up while the worker is busy
            try:
                httpx.post(url + "/v1/timeline", json={"segments": [{"prompt": f"left {k}", "seconds": 60}],
                                                       "steps": 1}, timeout=3)
            except httpx.TimeoutException:
                gave_up.append(k)
        leaving = [threading.Thread(target=leave, args=(k,)) for k in range(3)]
        for t in leaving:
            t.start()
        for t in leaving:
            t.join(60)
        batcher = app.state.batcher

        def all_cancelled() -> bool:  # the three jobs queued behind the blocked call, each cancelled by its client
            queued = [item for lane in batcher._lanes for item in lane]
            return len(queued) == 3 and all(f.cancelled() for _, f in queued)
        deadline = time.monotonic() + 30  # events and states, not a guess of how long a busy machine takes
        while not all_cancelled() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert sorted(gave_up) == [0, 1, 2] and all_cancelled()
        gate.release.set()
        first.join(30)
        r = httpx.post(url + "/v1/generate", json={"prompt": "after", "seconds": 2, "steps": 1}, timeout=30)
        assert r.status_code == 200
    assert not [p for p in gate.prompts if p.startswith("left")] and app.state.batcher.dropped == 3


def closed_by_server(sock: socket.socket, timeout: float = 30.0) -> bool:
    """Whether the server ended this connection: an orderly close reads as b"", and a close with our unread
    headers still in its buffer arrives as a reset. A timeout (the server kept it open) raises."""
    sock.settimeout(timeout)
    try:
        return sock.recv(100) == b""
    except ConnectionResetError:
        return True


def refused_by_server(sock: socket.socket, timeout: float = 30.0) -> bool:
    """Whether the server answered this connection with its JSON 503 (before any request) and then ended it in
    order: everything up to the end is read; a reset (the answer lost) raises."""
    sock.settimeout(timeout)
    data = b""
    while chunk := sock.recv(4096):
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    return (head.startswith(b"HTTP/1.1 503") and b"content-type: application/json" in head
            and json.loads(body)["error"].startswith("the server is at its limit of"))


def test_a_half_open_connection_is_closed():
    """A client that sends part of its headers and waits is disconnected after the header timeout."""
    from stablemofusion.serve.worker import ThreadWorker

    class NoModel(ThreadWorker):
        def __init__(self):
            from stablemofusion.serve.worker import ServedModel

            self.model = ServedModel(fps=20.0, min_frames=40, max_frames=196, student=False, steps=10, guidance=2.5)

        def start(self):
            pass

        def close(self):
            pass

    with live_server(create_app(NoModel()), header_timeout=0.5) as url:
        port = int(url.rsplit(":", 1)[1])
        socks = [socket.create_connection(("127.0.0.1", port)) for _ in range(5)]
        for s in socks:
            s.sendall(b"GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # never ends its headers
        # the timeout is a safety net only: the server closes them after its 0.5 s header timeout
        assert all(closed_by_server(s, timeout=60) for s in socks)
        for s in socks:
            s.close()


BVH_CASES = {
    "frame time 10000": ("Frame Time: 0.05", "Frame Time: 10000"),
    "frame time 1e9": ("Frame Time: 0.05", "Frame Time: 1e9"),
    "frame time nan": ("Frame Time: 0.05", "Frame Time: nan"),
    "channels inf": ("CHANNELS 3", "CHANNELS inf"),
    "offset nan": ("OFFSET 0.000000 0.000000 0.000000", "OFFSET nan 0 0"),
    "values 1e305": ("LAST", "1e305"),
    "frames 10 million": ("Frames: 2", "Frames: 10000000"),
}


@pytest.fixture(scope="module")
def small_bvh(tmp_path_factory) -> str:
    from stablemofusion.motion.files import load_motion, save_bvh

    path = tmp_path_factory.mktemp("bvh") / "w.bvh"
    save_bvh(load_motion("example:wave-both-hands").joints[:2], path)
    return path.read_text()


@pytest.mark.parametrize("case", BVH_CASES)
def test_convert_rejects_absurd_bvh_values(pipe, small_bvh, case):
    old, new = BVH_CASES[case]
    if old == "LAST":
        last = small_bvh.rstrip("\n").rsplit("\n", 1)[1]
        text = small_bvh.replace(last, " ".join([new] * len(last.split())))
    else:
        assert old in small_bvh
        text = small_bvh.replace(old, new, 1)
    r = post_raw(create_app(pipe), "/v1/convert?filename=w.bvh", text.encode(), OCTETS)
    assert 400 <= r.status_code < 500 and "w.bvh" in r.json()["error"]


@pytest.mark.parametrize("array", [np.zeros((15_000_000 // 66, 22, 3), np.int8), np.full((10, 22, 3), 1e305),
                                   np.zeros((3000, 22, 3), np.float32)])
def test_convert_bounds_npy_uploads(pipe, array):
    buf = io.BytesIO()
    np.save(buf, array)
    r = post_raw(create_app(pipe), "/v1/convert?filename=m.npy", buf.getvalue(), OCTETS)
    assert r.status_code == 422


def test_convert_runs_off_the_event_loop(pipe, monkeypatch):
    """While an upload is parsed, /v1/health answers."""
    import stablemofusion.serve.app as app_module

    def slow(data, filename):
        time.sleep(1.5)
        return b"{}"
    monkeypatch.setattr(app_module, "convert_upload", slow)
    app = create_app(pipe)
    call(app, ("POST", "/v1/generate", {"prompt": "warm", "seconds": 2, "steps": 1}))

    async def go():
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
            upload = asyncio.ensure_future(c.post("/v1/convert?filename=a.bvh", content=b"x", headers=OCTETS))
            await asyncio.sleep(0.2)
            health = await c.get("/v1/health")
            answered_first = not upload.done()  # were the parse on the event loop, health would wait for it
            await upload
            return health, answered_first
    health, answered_first = asyncio.run(go())
    assert health.status_code == 200 and answered_first


class Spy(Poisoned):
    """The tiny pipeline, recording the keyword arguments of every call."""

    def __init__(self, pipe):
        super().__init__(pipe)
        self.kwargs = []

    def __call__(self, prompts, **kw):
        self.kwargs.append(kw)
        return self._pipe(prompts, **kw)


def test_the_app_passes_seconds_to_the_pipeline(pipe):
    """The server converts no seconds to frames itself: the pipeline gets the seconds."""
    spy = Spy(pipe)
    (r,) = call(create_app(spy), ("POST", "/v1/generate", {"prompt": "walk", "seconds": 2.5, "steps": 1}))
    assert r.status_code == 200 and spy.kwargs[-1]["seconds"] == [2.5] and r.json()["frames"] == 48


def test_the_app_leaves_the_guidance_to_the_model(pipe):
    """A request without a guidance scale gets the model's default (its config's), not one of the server's."""
    spy = Spy(pipe)
    r, s = call(create_app(spy), ("POST", "/v1/generate", {"prompt": "walk", "seconds": 2.0, "steps": 1}),
                ("POST", "/v1/generate", {"prompt": "run", "seconds": 2.0, "steps": 1, "guidance": 1.5}))
    seen = {kw.get("guidance_scale") for kw in spy.kwargs}
    assert r.status_code == s.status_code == 200 and seen == {1.5, None}  # (a warm-up call too)


def test_no_module_global_pipeline():
    import stablemofusion.serve.batcher as batcher
    import stablemofusion.serve.worker as worker

    for module in (batcher, worker):
        assert not [n for n in vars(module) if re.search("pipe", n, re.I) and not callable(vars(module)[n])]


def _npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


_WALK = np.cumsum(np.full((40, 22, 3), 0.01), axis=1)  # 40 frames of a 22-joint body with bones of 1.7 cm


@pytest.mark.parametrize("data, words", [
    (_npy(_WALK)[:-100], "truncated"),
    (_npy(_WALK)[:128], "truncated"),
    (_npy(_WALK) + b"1234", "extra bytes"),
    (_npy(np.zeros((2, 40, 22, 3, 1))), "neither joints"),
    (_npy(np.float32(3.0)), "neither joints"),
    (_npy(_WALK.astype(complex)), "not real numbers"),
])
def test_convert_answers_every_malformed_npy_with_a_4xx(pipe, data, words):
    r = post_raw(create_app(pipe), "/v1/convert?filename=m.npy", data, OCTETS)
    assert r.status_code == 422 and words in r.json()["error"]


def test_convert_reads_a_fortran_order_npy(pipe):
    r = post_raw(create_app(pipe), "/v1/convert?filename=m.npy", _npy(np.asfortranarray(_WALK)), OCTETS)
    assert r.status_code == 200 and np.allclose(r.json()["joints"], _WALK, atol=1e-4)


def test_a_header_block_over_the_limit_sent_in_one_write_is_refused(pipe):
    """uvicorn bounds headers only while they are incomplete: 100 kB of headers in one write reached the app."""
    from stablemofusion.serve.server_limits import MAX_HEADER_BYTES

    filler = {f"X-Filler-{i}": "a" * 1000 for i in range(100)}  # 100 kB, sent by httpx in one write
    with live_server(create_app(pipe)) as url:
        big = httpx.get(url + "/v1/health", headers=filler, timeout=60)
        small = httpx.get(url + "/v1/health", headers={"X-Small": "a" * 1000}, timeout=60)
    assert big.status_code == 431 and f"larger than {MAX_HEADER_BYTES} bytes" in big.json()["error"]
    assert small.status_code != 431


def test_idle_connections_cannot_lock_everyone_out(pipe):
    """300 connections that never finish their headers (more than the 256 the server serves at once, all from one
    address): the oldest of them are refused as new ones come (a JSON 503, then an orderly close: never a reset), so
    health and a generate request are answered."""
    with live_server(create_app(pipe)) as url:
        port = int(url.rsplit(":", 1)[1])
        for _ in range(600):  # the worker warms first (a safety net of 60 s)
            if httpx.get(url + "/v1/health", timeout=30).status_code == 200:
                break
            time.sleep(0.1)
        socks = []
        try:
            for i in range(300):
                s = socket.create_connection(("127.0.0.1", port))
                if i % 2:
                    s.sendall(b"GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # half its headers
                socks.append(s)
            time.sleep(0.5)
            health = httpx.get(url + "/v1/health", timeout=30)
            made = httpx.post(url + "/v1/generate", json={"prompt": "a person walks", "seconds": 2, "steps": 1},
                              timeout=60)
            closed = sum(refused_by_server(s) for s in socks[:40])  # the oldest were refused by the server
        finally:
            for s in socks:
                s.close()
    assert health.status_code == 200 and health.json()["status"] == "ok"
    assert made.status_code == 200 and made.json()["frames"] == 40
    assert closed == 40


def test_a_request_over_the_connection_cap_gets_a_json_503():
    """Past the connection cap a request is answered, in JSON with a Retry-After, as every other refusal is (uvicorn's
    own cap answered in plain text); under it the app answers."""
    from stablemofusion.serve.server import Capped

    class Crowded:
        connections, refused = set(range(6)), {0}

    async def app(scope, receive, send):
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"ok"})

    for limit, want in ((4, 503), (5, 200)):
        r = call(Capped(app, Crowded, limit), ("GET", "/v1/health", None))[0]
        assert r.status_code == want
    r = call(Capped(app, Crowded, 4), ("POST", "/v1/generate", {"prompt": "a person walks"}))[0]
    assert r.headers["content-type"] == "application/json" and r.headers["retry-after"] == "1"
    assert r.json() == {"error": "the server is at its limit of 256 connections; retry shortly"}
    # a live stream over the cap is told so and closed with 1013 (try again later), as at the stream limit
    from starlette.testclient import TestClient
    from starlette.websockets import WebSocketDisconnect

    with TestClient(Capped(app, Crowded, 4)).websocket_connect("/v1/stream") as ws:
        assert ws.receive_json() == {"type": "error", "error": r.json()["error"]}
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_json()
    assert closed.value.code == 1013


def test_uploads_are_held_against_one_budget(pipe):
    """Uploads reserve their size before a byte is read: past the server-wide budget, 503 at once; each upload
    gives its share back when answered."""
    import stablemofusion.serve.app as app_module

    started = []

    def slow(data, filename):
        started.append(len(data))
        time.sleep(0.5)
        return b"{}"
    app = create_app(pipe, upload_budget=3 * 1000)
    original = app_module.convert_upload
    app_module.convert_upload = slow
    try:
        async def go():
            transport = httpx.ASGITransport(app=app)
            async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
                post = lambda: c.post("/v1/convert?filename=a.bvh", content=b"x" * 1000, headers=OCTETS)  # noqa: E731
                first = await asyncio.gather(*[post() for _ in range(5)])
                again = await post()  # the budget is back once the first were answered
                return first, again
        first, again = asyncio.run(go())
    finally:
        app_module.convert_upload = original
    codes = sorted(r.status_code for r in first)
    assert codes == [200, 200, 200, 503, 503] and again.status_code == 200
    assert all("other uploads" in r.json()["error"] for r in first if r.status_code == 503)


def test_a_bvh_of_too_many_frames_or_too_large_a_hierarchy_is_refused_before_parsing(pipe):
    from stablemofusion.serve.server_limits import MAX_CONVERT_FRAMES, MAX_HIERARCHY_BYTES

    head = b"HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n}\n"
    many = head + f"MOTION\nFrames: {MAX_CONVERT_FRAMES + 1}\nFrame Time: 0.001\n".encode() + b"0 0 0 0 0 0\n" * 10
    deep = b"HIERARCHY\n" + b"{" * (MAX_HIERARCHY_BYTES + 1) + b"\nMOTION\nFrames: 10\nFrame Time: 0.05\n"
    app = create_app(pipe)
    assert "more than the viewer reads" in post_raw(app, "/v1/convert?filename=m.bvh", many, OCTETS).json()["error"]
    r = post_raw(app, "/v1/convert?filename=m.bvh", deep, OCTETS)
    assert r.status_code == 422 and "HIERARCHY has" in r.json()["error"]
