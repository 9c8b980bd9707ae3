"""The supervised worker process: restarted when it dies (its request in flight answered 503), health
honest about it; `smf serve` reads the checkpoint config (no pipeline in the parent); SIGTERM stops the
worker promptly."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import threading
import time

import httpx

from stablemofusion.serve import ProcessWorker, ServedModel, WorkerSpec, create_app

from serve_helpers import free_port

LONG = {"segments": [{"prompt": "a person walks", "seconds": 60}, {"prompt": "a person runs", "seconds": 60}],
        "steps": 50, "seed": 0}
SHORT = {"prompt": "a person walks", "seconds": 2, "seed": 1, "steps": 1}
ANY_COST = 1e9  # LONG keeps the worker busy: far more work than the server takes by default (MAX_REQUEST_COST)


async def until_health(client, ready: bool = True, seen: list | None = None, polls: int = 1200) -> dict:
    """Poll /v1/health until it is (not) ready; a safety net of ``polls`` x 0.1 s (the states are what is
    checked); ``seen`` collects (status code, status, warm) of every poll."""
    for _ in range(polls):
        r = await client.get("/v1/health")
        body = r.json()
        if seen is not None:
            seen.append((r.status_code, body["status"], body["worker"]["warm"]))
        if (r.status_code == 200) == ready:
            return body
        await asyncio.sleep(0.1)
    raise AssertionError(f"health never became {'ready' if ready else 'not ready'}: {body}")


def test_a_killed_worker_is_restarted_and_its_request_gets_503(pipe, checkpoint):
    worker = ProcessWorker(WorkerSpec(str(checkpoint), "cpu", threads=1), ServedModel.of(pipe))
    app = create_app(worker, max_request_cost=ANY_COST)

    async def until_ready(client, seen):
        return await until_health(client, True, seen)

    async def go():
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1", timeout=120) as c:
            worker.start()
            first_start = []
            body = await until_ready(c, first_start)
            pid = body["worker"]["pid"]
            long = asyncio.ensure_future(c.post("/v1/timeline", json=LONG))
            for _ in range(600):
                if worker.health()["busy"]:
                    break
                await asyncio.sleep(0.05)
            os.kill(pid, signal.SIGKILL)  # as an out-of-memory kill would
            in_flight = await long
            restart = []
            after = await until_ready(c, restart)
            ok = await c.post("/v1/generate", json=SHORT)
            return first_start, in_flight, restart, after, ok, pid
    try:
        first_start, in_flight, restart, after, ok, pid = asyncio.run(go())
    finally:
        worker.close()
    # not ready before the model was loaded and warm
    assert first_start[0][0] == 503 and first_start[-1] == (200, "ok", True)
    assert all(code == 503 and not warm for code, _, warm in first_start[:-1])
    assert in_flight.status_code == 503 and "restarted" in in_flight.json()["error"]
    assert restart[0][0] == 503 and restart[0][1] in ("restarting", "starting", "warming")  # honest meanwhile
    assert after["worker"]["restarts"] == 1 and after["worker"]["pid"] != pid
    assert ok.status_code == 200 and ok.json()["frames"] == 40


def test_serve_reads_the_config_and_loads_no_pipeline_in_the_parent(checkpoint, monkeypatch):
    import uvicorn

    from stablemofusion.cli.main import main
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    def refuse(*a, **kw):
        raise AssertionError("the parent loaded a pipeline")
    apps = []
    monkeypatch.setattr(MotionPipeline, "from_pretrained", refuse)
    monkeypatch.setattr(uvicorn.Server, "run", lambda self, sockets=None: apps.append(self.config.app))
    assert main(["serve", "--checkpoint", str(checkpoint), "--port", "8123", "--allow-host", "motion.lan"]) == 0
    worker = apps[0].state.worker
    assert isinstance(worker, ProcessWorker) and worker.model.fps == 20.0 and worker.health()["state"] == "stopped"


def test_sigterm_stops_the_worker_and_answers_requests_in_flight_in_json(checkpoint, tmp_path):
    port = free_port()
    code = "import sys; from stablemofusion.cli.main import main; sys.exit(main())"
    server = subprocess.Popen([sys.executable, "-c", code, "serve", "--checkpoint", str(checkpoint), "--port",
                               str(port), "--threads", "1", "--max-request-cost", str(ANY_COST)], env={**os.environ, "OMP_NUM_THREADS": "1"},
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        pid = None
        for _ in range(600):  # at most 120 s
            time.sleep(0.2)
            try:
                r = httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=2)
            except httpx.TransportError:
                continue
            if r.status_code == 200:
                pid = r.json()["worker"]["pid"]
                break
        assert pid is not None, "the server did not become ready"
        answers, not_connected = [], []

        def request():  # longer than the graceful shutdown: cancelled by uvicorn, answered by us
            try:
                r = httpx.post(f"http://127.0.0.1:{port}/v1/timeline", json={**LONG, "footskate": "loop"},
                               timeout=120)
            except httpx.ConnectError:  # this client connected after the server stopped listening: never in flight
                not_connected.append(1)
                return
            answers.append((r.status_code, r.headers["content-type"], r.json()))
        clients = [threading.Thread(target=request) for _ in range(6)]  # together far longer than the 5 s grace
        for c in clients:
            c.start()
        while not httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=5).json()["worker"]["busy"]:
            time.sleep(0.05)
        os.kill(pid, signal.SIGSTOP)  # nothing in flight can finish now, however fast this machine is
        server.send_signal(signal.SIGTERM)
        server.wait(120)  # raises if it does not stop (a safety net, not a speed figure)
        for c in clients:
            c.join(60)
        # every request in flight at SIGTERM is answered in JSON 503 (never a plain-text 500): the server shutting
        # down, or its watchdog finding the stopped worker first
        assert len(answers) + len(not_connected) == 6 and len(answers) >= 1, (answers, not_connected)
        assert all(ct == "application/json" for _, ct, _ in answers), answers
        assert all(code == 503 and ("shutting down" in body["error"] or "restarted" in body["error"])
                   for code, _, body in answers), answers
        for _ in range(50):
            if not _alive(pid):
                break
            time.sleep(0.1)
        assert not _alive(pid)
    finally:
        if server.poll() is None:
            server.kill()
            server.wait(10)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (exited, not yet reaped by init) counts as stopped
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ", 1)[1][0] != "Z"
    except OSError:
        return False


def test_a_stopped_worker_is_found_by_its_heartbeat_answered_503_and_restarted(pipe, checkpoint):
    """SIGSTOP (a frozen process) while a long request runs: health says not ready once the heartbeat is older
    than WORKER_BEAT_TIMEOUT_S, the request gets a 503, and a new worker answers after."""
    from stablemofusion.serve.server_limits import WORKER_BEAT_TIMEOUT_S

    worker = ProcessWorker(WorkerSpec(str(checkpoint), "cpu", threads=1), ServedModel.of(pipe))
    app = create_app(worker, max_request_cost=ANY_COST)
    until = until_health

    async def go():
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1", timeout=300) as c:
            worker.start()
            pid = (await until(c, True))["worker"]["pid"]
            long = asyncio.ensure_future(c.post("/v1/timeline", json=LONG))
            for _ in range(600):
                if worker.health()["busy"]:
                    break
                await asyncio.sleep(0.05)
            os.kill(pid, signal.SIGSTOP)
            stopped_at = time.monotonic()
            down = await until(c, False)
            noticed = time.monotonic() - stopped_at
            in_flight = await long
            after = await until(c, True)
            ok = await c.post("/v1/generate", json=SHORT)
            return pid, down, noticed, in_flight, after, ok

    try:
        pid, down, noticed, in_flight, after, ok = asyncio.run(go())
    finally:
        worker.close()
    assert down["worker"]["state"] in ("unresponsive", "restarting", "starting", "warming")
    assert noticed >= WORKER_BEAT_TIMEOUT_S - 1.5  # found by the heartbeat's age, not by chance
    assert in_flight.status_code == 503 and "restarted" in in_flight.json()["error"]
    assert after["worker"]["pid"] != pid and after["worker"]["restarts"] == 1
    assert ok.status_code == 200 and ok.json()["frames"] == 40
