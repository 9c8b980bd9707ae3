"""Replicas of `smf serve` behind HAProxy with the shipped configuration (docs/replicas.md), on 127.0.0.1 only.

In one run:
1. throughput: ``--clients`` clients sending seeded /v1/generate requests for ``--seconds`` s to one replica
   directly, then through the balancer to all replicas (answers a second);
2. a replica killed (SIGKILL of its process group) a third of the way into ``--fault-seconds`` of the same load
   through the balancer, and started again at two thirds: requests that failed (no 200), the slowest answer, and
   answers that differ from the same seed's answer of a replica alone (joints more than 1e-4 m apart);
3. a replica stopped with SIGTERM (it drains) under the same load: failed requests;
4. live streams: ``--streams`` WebSocket streams through the balancer; every replica serving one is killed; each
   client reconnects when its stream breaks and sends its prompt again: frames received before and after, and
   the longest gap a client saw.

Every loop is bounded in count and time. Prints one JSON report.

    python benchmarks/serve_replicas.py [--replicas 2] [--clients 8] [--seconds 20] [--fault-seconds 60]
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import signal
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "serve"))
from replica_helpers import Replicas, wait_ready  # noqa: E402

PROMPTS = ["a person walks forward", "a tired man shuffles forward", "someone waves both hands",
           "a person runs in a circle", "a proud soldier marches", "an old woman bows"]
TIMEOUT_S = 120.0


def body(i: int) -> dict:
    return {"prompt": PROMPTS[i % len(PROMPTS)], "seconds": 2, "seed": i}


def joints_of(r: httpx.Response) -> np.ndarray:
    return np.load(io.BytesIO(r.content), allow_pickle=False)


async def load(url: str, clients: int, seconds: float, first: int = 0) -> dict:
    """``clients`` clients sending one request after another for ``seconds``: answers by status, the slowest
    answer, and each 200's joints by seed."""
    ok, failed, slowest, joints, replicas = 0, [], 0.0, {}, {}
    end = time.monotonic() + seconds
    counter = iter(range(first, first + 10**6))

    async def client(c: httpx.AsyncClient):
        nonlocal ok, slowest
        while time.monotonic() < end:
            i = next(counter)
            t0 = time.monotonic()
            try:
                r = await c.post(f"{url}/v1/generate?format=npy", json=body(i), timeout=TIMEOUT_S)
            except httpx.HTTPError as e:
                failed.append(f"{type(e).__name__}")
                continue
            slowest = max(slowest, time.monotonic() - t0)
            if r.status_code == 200:
                ok += 1
                joints[i] = joints_of(r)
                name = r.headers.get("x-smf-replica", "direct")
                replicas[name] = replicas.get(name, 0) + 1
            else:
                failed.append(f"{r.status_code} {r.text[:80]}")

    t0 = time.monotonic()
    async with httpx.AsyncClient(limits=httpx.Limits(max_connections=clients)) as c:
        await asyncio.gather(*[client(c) for _ in range(clients)])
    took = time.monotonic() - t0
    return {"answered": ok, "per_s": ok / took, "failed": len(failed), "failures": sorted(set(failed))[:5],
            "slowest_s": slowest, "by_replica": replicas, "joints": joints}


async def faulty_load(reps: Replicas, k: int, sig: int, clients: int, seconds: float, first: int,
                      restart: bool) -> dict:
    """:func:`load` through the balancer, replica ``k`` sent ``sig`` a third of the way in (and started again at
    two thirds when ``restart``)."""
    async def fault():
        await asyncio.sleep(seconds / 3)
        reps.signal(k, sig)
        if restart:
            await asyncio.sleep(seconds / 3)
            await asyncio.to_thread(reps.replicas[k].wait, 30)
            reps.start_replica(k)
    result, _ = await asyncio.gather(load(reps.url, clients, seconds, first), fault())
    return result


def differing(joints: dict, url: str, most: int = 24) -> tuple[int, int]:
    """How many of (at most ``most``) answers differ from the same request to ``url`` (a replica alone)."""
    checked = wrong = 0
    for i in sorted(joints)[:: max(1, len(joints) // most)][:most]:
        r = httpx.post(f"{url}/v1/generate?format=npy", json=body(i), timeout=TIMEOUT_S)
        checked += 1
        wrong += r.status_code != 200 or float(np.abs(joints_of(r) - joints[i]).max()) > 1e-4
    return checked, wrong


async def streams(reps: Replicas, count: int, seconds: float) -> dict:
    """``count`` live streams through the balancer; the replicas serving them killed at a third of ``seconds``;
    each client reconnects (at most 5 times) and sends its prompt again."""
    from websockets.asyncio.client import connect

    ws_url = reps.url.replace("http://", "ws://") + "/v1/stream"
    end = time.monotonic() + seconds
    kill_at = time.monotonic() + seconds / 3
    before, after, reconnects, gaps, killed = [0] * count, [0] * count, [0] * count, [0.0] * count, []

    async def client(n: int):
        last = time.monotonic()
        while time.monotonic() < end and reconnects[n] <= 5:
            try:
                async with connect(ws_url, open_timeout=10) as ws:
                    await ws.send(json.dumps({"prompt": PROMPTS[n % len(PROMPTS)], "seed": n}))
                    while time.monotonic() < end:
                        m = json.loads(await asyncio.wait_for(ws.recv(), timeout=10))
                        if m.get("type") != "frames":
                            continue
                        now = time.monotonic()
                        gaps[n] = max(gaps[n], now - last)
                        last = now
                        (before if now < kill_at else after)[n] += len(m["joints"])
                    return
            except Exception:  # the replica died under it (or the balancer refused): connect again
                reconnects[n] += 1
                await asyncio.sleep(0.2)

    async def kill():
        await asyncio.sleep(seconds / 3)
        for k, url in enumerate(reps.urls):  # every replica that serves a stream (its health counts them)
            if httpx.get(f"{url}/v1/health", timeout=5).json()["streams"]["active"] > 0:
                reps.signal(k, signal.SIGKILL)
                killed.append(k)

    await asyncio.gather(*[client(n) for n in range(count)], kill())
    return {"streams": count, "replicas_killed": len(killed), "frames_before": sum(before), "frames_after": sum(after),
            "streams_continued": sum(a > 0 for a in after), "reconnects": sum(reconnects),
            "longest_gap_s": max(gaps)}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--replicas", type=int, default=2)
    p.add_argument("--clients", type=int, default=8)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--fault-seconds", type=float, default=60.0)
    p.add_argument("--streams", type=int, default=2)
    a = p.parse_args()
    report = {"replicas": a.replicas, "clients": a.clients}
    with tempfile.TemporaryDirectory() as tmp, Replicas(a.replicas, Path(tmp)) as reps:
        one = asyncio.run(load(reps.urls[0], a.clients, a.seconds))
        many = asyncio.run(load(reps.url, a.clients, a.seconds, first=10**5))
        report["one_replica"] = {k: v for k, v in one.items() if k != "joints"}
        report["balanced"] = {k: v for k, v in many.items() if k != "joints"}
        killed = asyncio.run(faulty_load(reps, 0, signal.SIGKILL, a.clients, a.fault_seconds, 2 * 10**5, True))
        wait_ready(reps.urls[0])
        checked, wrong = differing(killed["joints"], reps.urls[1])
        report["replica_killed"] = {**{k: v for k, v in killed.items() if k != "joints"}, "checked": checked,
                                    "differ": wrong}
        wait_ready(reps.url, 60, replicas=a.replicas)
        drained = asyncio.run(faulty_load(reps, 1, signal.SIGTERM, a.clients, a.seconds, 3 * 10**5, True))
        report["replica_stopped"] = {k: v for k, v in drained.items() if k != "joints"}
        wait_ready(reps.urls[1])
        wait_ready(reps.url, 60, replicas=a.replicas)
        report["live_streams"] = asyncio.run(streams(reps, a.streams, a.seconds))
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
