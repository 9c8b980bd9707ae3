"""Overload past the connection cap: many clients at once against one `smf serve` on 127.0.0.1.

Starts `smf serve` (the portable runtime by default; ``--engine auto`` for PyTorch) from this checkout or from
``--source DIR`` (another checkout: the version before a change), waits until it is ready, then for ``--seconds``:
- ``--clients`` clients (each its own connection pool) send seeded 2 s /v1/generate requests one after another;
- a prober (a process of its own) asks /v1/health every 0.2 s on a new connection.
Counts each request's outcome: 200, a JSON 503 (refused with a reason), any other status or content type, and
transport errors (a reset or a closed connection without an answer); and each health probe's answer and time.
Every loop is bounded in count and time. Prints one JSON report.

    python benchmarks/serve_overload.py [--clients 500] [--seconds 30] [--engine onnx] [--source DIR]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import resource
import socket
import subprocess
import sys
import time

import httpx

HOST = "127.0.0.1"  # never any other address
SERVE = "import sys; from stablemofusion.cli.main import main; sys.exit(main())"


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


async def run(url: str, clients: int, seconds: float) -> dict:
    outcomes: dict[str, int] = {}
    end = time.monotonic() + seconds

    def count(what: str) -> None:
        outcomes[what] = outcomes.get(what, 0) + 1

    async def client(n: int) -> None:
        async with httpx.AsyncClient(timeout=60) as c:
            i = n
            while time.monotonic() < end:
                try:
                    r = await c.post(f"{url}/v1/generate", json={"prompt": "a person walks", "seconds": 2, "seed": i})
                    ok_json = r.headers.get("content-type", "").startswith("application/json")
                    if r.status_code == 200:
                        count("200")
                    elif r.status_code == 503 and ok_json and "error" in r.json():
                        count("503 json")
                        await asyncio.sleep(float(r.headers.get("retry-after", 1)))
                    else:
                        count(f"{r.status_code} {r.headers.get('content-type', '')}")
                except httpx.HTTPError as e:
                    count(type(e).__name__)
                    await asyncio.sleep(0.5)
                i += clients

    # the prober is a process of its own: in this one it would wait for the 500 clients' turns, not the server
    prober = subprocess.Popen([sys.executable, __file__, "--probe", url, "--seconds", str(seconds)],
                              stdout=subprocess.PIPE, text=True)
    await asyncio.gather(*[client(n) for n in range(clients)])
    health = [tuple(x) for x in json.loads(prober.communicate(timeout=120)[0])]
    answered = [t for ok, _, t in health if ok]
    total = sum(outcomes.values())
    return {"requests": total, "outcomes": outcomes,
            "answered_share": sum(v for k, v in outcomes.items() if k in ("200", "503 json")) / max(1, total),
            "health_probes": len(health), "health_answered": len(answered),
            "health_200": sum(code == 200 for _, code, _ in health),
            "health_slowest_s": max(answered, default=None)}


def probe(url: str, seconds: float) -> None:
    """Ask ``url``'s health every 0.2 s on a new connection for ``seconds``; print [[answered in JSON, status,
    seconds], ...] (status 0: no answer)."""
    health, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        t0 = time.monotonic()
        try:
            r = httpx.get(f"{url}/v1/health", timeout=10)
            json_answer = r.headers.get("content-type", "").startswith("application/json")
            health.append((json_answer, r.status_code, time.monotonic() - t0))
        except httpx.HTTPError:
            health.append((False, 0, time.monotonic() - t0))
        time.sleep(0.2)
    print(json.dumps(health))


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--clients", type=int, default=500)
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--engine", default="onnx")
    p.add_argument("--source", default=None, help="run the server from this checkout instead")
    p.add_argument("--probe", default=None, help=argparse.SUPPRESS)  # the health prober's own process
    a = p.parse_args()
    if a.probe:
        probe(a.probe, a.seconds)
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, 8192), hard))  # 500 clients need 500 sockets here
    port = free_port()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    if a.source:
        env["PYTHONPATH"] = a.source
    server = subprocess.Popen([sys.executable, "-c", SERVE, "serve", "--host", HOST, "--port", str(port), "--engine",
                               a.engine, "--threads", "1"], env=env, cwd=a.source or None,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"http://{HOST}:{port}"
    try:
        for _ in range(3000):  # at most 300 s
            try:
                if httpx.get(f"{url}/v1/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        report = {"clients": a.clients, "seconds": a.seconds, "engine": a.engine, "source": a.source or "this checkout",
                  **asyncio.run(run(url, a.clients, a.seconds))}
    finally:
        server.terminate()
        server.wait(30)
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
