"""Replicas of `smf serve` (the portable runtime) behind HAProxy with the shipped configuration, on loopback: requests
spread over the replicas, a replica killed or stopped under load costs no request, a live stream whose replica
dies reconnects and continues, and the balancer answers in JSON when no replica is up."""

from __future__ import annotations

import asyncio
import io
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from replica_helpers import HAPROXY, Replicas, haproxy_available, wait_ready
from stablemofusion.serve.balancer import haproxy_config, haproxy_env, shipped_config

pytestmark = pytest.mark.skipif(not haproxy_available(), reason="needs HAProxy (Debian's haproxy; .ci/run installs it)")
DOCS = Path(__file__).resolve().parents[2] / "docs" / "replicas.md"


def body(i: int) -> dict:
    return {"prompt": ["a person walks forward", "someone waves both hands"][i % 2], "seconds": 2, "seed": i}


@pytest.fixture(scope="module")
def reps(tmp_path_factory):
    with Replicas(2, tmp_path_factory.mktemp("replicas")) as r:
        yield r


def ready_again(reps: Replicas, k: int) -> None:
    reps.replicas[k].wait(30)
    reps.start_replica(k)
    wait_ready(reps.urls[k])
    wait_ready(reps.url, 60, replicas=reps.count)


async def load_with_fault(reps: Replicas, k: int, sig: int, clients: int = 4, after: int = 8, limit_s: float = 120.0):
    """Seeded generate requests through the balancer; once both replicas have answered, replica k is sent ``sig``,
    and the load goes on until ``after`` more answers (waited for, not timed: a loaded machine is slow)."""
    answers, failures, served, since = {}, [], set(), [0]
    faulted = asyncio.Event()
    deadline = time.monotonic() + limit_s

    async def client(n: int, c: httpx.AsyncClient):
        i = n
        while time.monotonic() < deadline and since[0] < after:
            try:
                r = await c.post(f"{reps.url}/v1/generate?format=npy", json=body(i), timeout=120)
                if r.status_code == 200:
                    answers[i] = (np.load(io.BytesIO(r.content)), r.headers["x-smf-replica"])
                    served.add(r.headers["x-smf-replica"])
                    since[0] += faulted.is_set()
                else:
                    failures.append((r.status_code, r.text))
            except httpx.HTTPError as e:
                failures.append(repr(e))
            i += clients

    async def fault():
        while time.monotonic() < deadline and not (len(served) == reps.count and len(answers) >= 2 * clients):
            await asyncio.sleep(0.05)
        reps.signal(k, sig)
        faulted.set()

    async with httpx.AsyncClient() as c:
        await asyncio.gather(fault(), *[client(n, c) for n in range(clients)])
    return answers, failures, since[0]


def test_the_docs_show_the_configuration_that_is_tested():
    assert shipped_config().strip() in DOCS.read_text(encoding="utf-8")


def test_more_replicas_get_a_server_line_each_in_both_backends(tmp_path):
    text = haproxy_config(3)
    for k in (1, 2, 3):
        assert text.count(f'server r{k} "${{SMF_REPLICA_{k}}}"') == 2
    (tmp_path / "h.cfg").write_text(text)
    env = {**os.environ, **haproxy_env("127.0.0.1:9", ["127.0.0.1:10", "127.0.0.1:11", "127.0.0.1:12"])}
    check = subprocess.run([HAPROXY, "-c", "-f", str(tmp_path / "h.cfg")], env=env, capture_output=True, text=True)
    assert check.returncode == 0, check.stdout + check.stderr


def test_requests_spread_over_the_replicas_and_answer_as_a_replica_alone(reps):
    through = [httpx.post(f"{reps.url}/v1/generate?format=npy", json=body(i), timeout=60) for i in range(4)]
    assert [r.status_code for r in through] == [200] * 4
    assert {r.headers["x-smf-replica"] for r in through} == {"r1", "r2"}
    alone = httpx.post(f"{reps.urls[1]}/v1/generate?format=npy", json=body(3), timeout=60)
    np.testing.assert_array_equal(np.load(io.BytesIO(through[3].content)), np.load(io.BytesIO(alone.content)))


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["killed", "stopped"])
def test_a_replica_that_dies_or_drains_under_load_costs_no_request(reps, sig):
    answers, failures, after = asyncio.run(load_with_fault(reps, 0, sig))
    assert failures == []
    assert after >= 8 and {name for _, name in answers.values()} == {"r1", "r2"}  # answers before and after
    ready_again(reps, 0)
    # a seeded request gives the same motion whichever replica answered it
    for i in sorted(answers)[:: max(1, len(answers) // 4)]:
        again = httpx.post(f"{reps.urls[0]}/v1/generate?format=npy", json=body(i), timeout=60)
        np.testing.assert_allclose(np.load(io.BytesIO(again.content)), answers[i][0], atol=1e-5)


def test_a_live_stream_whose_replica_dies_reconnects_and_continues(reps):
    from websockets.asyncio.client import connect
    from websockets.exceptions import WebSocketException

    async def go():
        received, reconnects, killed = [0, 0], 0, []
        end = time.monotonic() + 90  # a safety net: the test waits for frames, not for a time
        while time.monotonic() < end and reconnects < 4:
            try:
                async with connect(reps.url.replace("http", "ws") + "/v1/stream", open_timeout=10) as ws:
                    await ws.send(json.dumps({"prompt": "a person walks forward", "seed": 1}))
                    while time.monotonic() < end:
                        m = json.loads(await asyncio.wait_for(ws.recv(), timeout=10))
                        if m.get("type") != "frames":
                            continue
                        received[bool(killed)] += len(m["joints"])
                        if not killed and received[0] >= 40:  # the replica serving it dies
                            k = [k for k, u in enumerate(reps.urls)
                                 if httpx.get(f"{u}/v1/health", timeout=5).json()["streams"]["active"]][0]
                            reps.signal(k, signal.SIGKILL)
                            killed.append(k)
                        if killed and received[1] >= 40:
                            return received, reconnects, killed
            except (OSError, asyncio.TimeoutError, WebSocketException):  # its connection broke: connect again
                reconnects += 1
                await asyncio.sleep(0.2)
        return received, reconnects, killed

    (before, after), reconnects, killed = asyncio.run(go())
    assert killed and reconnects >= 1 and before >= 40 and after >= 40, (before, after, reconnects)
    ready_again(reps, killed[0])


def test_with_no_replica_up_the_balancer_answers_json_503(reps):
    for k in range(reps.count):
        reps.signal(k, signal.SIGKILL)
    for k in range(reps.count):
        reps.replicas[k].wait(30)
    deadline = time.monotonic() + 10
    while True:  # until the health checks have marked both down (2 failed checks, 1 s apart)
        r = httpx.post(f"{reps.url}/v1/generate", json=body(0), timeout=30)
        if r.status_code == 503 or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert r.status_code == 503 and r.headers["content-type"] == "application/json"
    assert r.json() == {"error": "no replica is ready; retry shortly"}
