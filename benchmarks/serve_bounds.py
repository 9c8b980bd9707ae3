"""The server's total bounds under attack, one row each: memory, connections, a stopped worker, heavy work,
malformed uploads, stream churn. Against `smf serve` (the shipped model unless --checkpoint) on 127.0.0.1 only,
a fresh server per attack (so one attack's state does not hide another's); every loop bounded in count and time.

1. uploads: 40 concurrent 16 MB uploads; the memory of the server and all its processes (idle, peak, 5 s after)
   and the slowest /v1/health meanwhile;
2. idle sockets: 300 connections that never finish their headers (half of them sent half a header); then
   /v1/health and a generate request;
3. stopped worker: SIGSTOP the worker while it generates a long request; seconds until health is not ready, the
   request's status and seconds, seconds until ready again;
4. heavy then light: a 120 s timeline (16 segments of 7.5 s, footskate loop), then 1 s later a 2 s request: the
   light request's seconds; and the same timeline at 6 steps (refused: over the work budget);
5. malformed uploads: the .npy kinds (Fortran order, truncated, header only, 5-D), BVH with NaN / huge values,
   a 16.5 MB BVH at Frame Time 0.001: the status of each (no 500), the memory peak;
6. stream churn: connect, send a prompt, close, for --churn-s seconds; then the server log's ERROR lines.

    python benchmarks/serve_bounds.py [--checkpoint RUN] [--churn-s 10] > report.json
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

from serve_faults import HOST, free_port, rss_mb

OCTETS = {"Content-Type": "application/octet-stream"}
HEAVY = {"segments": [{"prompt": "a person walks forward", "seconds": 7.5},
                      {"prompt": "a person waves both hands", "seconds": 7.5}] * 8, "footskate": "loop"}


@contextlib.contextmanager
def server(args, log: Path):
    """`smf serve` on a free loopback port, ready; yields (base URL, port, server pid)."""
    port = free_port()
    cmd = [sys.executable, "-m", "stablemofusion.cli.main", "serve", "--port", str(port), "--threads", "1"]
    cmd += ["--checkpoint", args.checkpoint] if args.checkpoint else []
    with open(log, "w") as err:
        proc = subprocess.Popen(cmd, env={**os.environ, "OMP_NUM_THREADS": "1"}, stdout=subprocess.DEVNULL, stderr=err)
    base = f"http://{HOST}:{port}"
    try:
        wait_ready(base, 300)
        yield base, port, proc.pid
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()


def wait_ready(base: str, limit_s: float) -> float:
    t = time.monotonic()
    while time.monotonic() - t < limit_s:
        with contextlib.suppress(httpx.TransportError):
            if httpx.get(base + "/v1/health", timeout=5).status_code == 200:
                return time.monotonic() - t
        time.sleep(0.1)
    raise SystemExit(f"not ready within {limit_s} s")


class Sampler:
    """Memory of the server's processes and /v1/health's answer time, every 0.1 s on a thread."""

    def __init__(self, base: str, pid: int):
        self.base, self.pid, self.rss, self.health_s, self._stop = base, pid, [], [], threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.is_set():
            self.rss.append(rss_mb(self.pid))
            t = time.monotonic()
            with contextlib.suppress(httpx.HTTPError):
                httpx.get(self.base + "/v1/health", timeout=10)
            self.health_s.append(time.monotonic() - t)
            time.sleep(0.1)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(30)


def post_many(base: str, url: str, bodies: list[bytes], headers: dict) -> list[int]:
    async def go():
        async with httpx.AsyncClient(base_url=base, timeout=120, limits=httpx.Limits(max_connections=None)) as c:
            rs = await asyncio.gather(*[c.post(url, content=b, headers=headers) for b in bodies],
                                      return_exceptions=True)
        return [r.status_code if isinstance(r, httpx.Response) else -1 for r in rs]
    return asyncio.run(go())


def uploads(args, log) -> dict:
    with server(args, log) as (base, _, pid):
        idle = rss_mb(pid)
        body = b"HIERARCHY\n" + b"0" * (16 * 1024 * 1024 - 20)
        with Sampler(base, pid) as s:
            codes = post_many(base, "/v1/convert?filename=big.bvh", [body] * 40, OCTETS)
        time.sleep(5)
        after = rss_mb(pid)
    return {"idle_mb": round(idle), "peak_mb": round(max(s.rss)), "after_5s_mb": round(after),
            "slowest_health_s": round(max(s.health_s), 2), "codes": {str(c): codes.count(c) for c in set(codes)}}


def idle_sockets(args, log) -> dict:
    with server(args, log) as (base, port, _):
        socks = []
        try:
            for i in range(300):
                s = socket.create_connection((HOST, port))
                if i % 2:
                    s.sendall(b"GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n")
                socks.append(s)
            time.sleep(0.5)
            t = time.monotonic()
            health = httpx.get(base + "/v1/health", timeout=30).status_code
            health_s = time.monotonic() - t
            t = time.monotonic()
            made = httpx.post(base + "/v1/generate", json={"prompt": "a person walks", "seconds": 2}, timeout=60)
            made_s = time.monotonic() - t
        finally:
            for s in socks:
                s.close()
    return {"health": health, "health_s": round(health_s, 2), "generate": made.status_code,
            "generate_s": round(made_s, 2)}


def stopped_worker(args, log) -> dict:
    with server(args, log) as (base, _, _):
        pid = httpx.get(base + "/v1/health", timeout=10).json()["worker"]["pid"]
        out = {}

        def long():
            t = time.monotonic()
            r = httpx.post(base + "/v1/timeline", json={**HEAVY, "footskate": "post"}, timeout=300)
            out["request"], out["request_s"] = r.status_code, round(time.monotonic() - t, 2)
        th = threading.Thread(target=long)
        th.start()
        time.sleep(0.3)
        os.kill(pid, signal.SIGSTOP)
        t = time.monotonic()
        while httpx.get(base + "/v1/health", timeout=10).status_code == 200 and time.monotonic() - t < 60:
            time.sleep(0.1)
        out["not_ready_after_s"] = round(time.monotonic() - t, 2)
        th.join(300)
        wait_ready(base, 300)
        out["ready_again_after_s"] = round(time.monotonic() - t, 2)
    return out


def heavy_then_light(args, log) -> dict:
    with server(args, log) as (base, _, _):
        out = {}

        def heavy():
            t = time.monotonic()
            r = httpx.post(base + "/v1/timeline", json={**HEAVY, "seed": 1}, timeout=300)
            out["heavy"], out["heavy_s"] = r.status_code, round(time.monotonic() - t, 2)
        th = threading.Thread(target=heavy)
        th.start()
        time.sleep(1.0)
        t = time.monotonic()
        r = httpx.post(base + "/v1/generate", json={"prompt": "a person bows", "seconds": 2, "seed": 2}, timeout=300)
        out["light"], out["light_s"] = r.status_code, round(time.monotonic() - t, 2)
        th.join(300)
        r = httpx.post(base + "/v1/timeline", json={**HEAVY, "steps": 6}, timeout=300)
        out["heavy_at_6_steps"] = r.status_code
    return out


def _npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def malformed(args, log) -> dict:
    from stablemofusion.motion.files import load_motion, save_bvh

    walk = load_motion("example:wave-both-hands").joints
    with tempfile.TemporaryDirectory() as tmp:
        save_bvh(walk[:2], Path(tmp) / "w.bvh")
        text = (Path(tmp) / "w.bvh").read_text()
    head, _, _ = text.partition("MOTION")
    row = text.rstrip("\n").rsplit("\n", 1)[1]
    cases = {
        "npy Fortran order": ("m.npy", _npy(np.asfortranarray(walk))),
        "npy truncated": ("m.npy", _npy(walk)[:-100]),
        "npy header only": ("m.npy", _npy(walk)[:128]),
        "npy 5-D": ("m.npy", _npy(np.zeros((2, 40, 22, 3, 1)))),
        "bvh NaN values": ("w.bvh", text.replace(row, " ".join(["nan"] * len(row.split()))).encode()),
        "bvh values 1e305": ("w.bvh", text.replace(row, " ".join(["1e305"] * len(row.split()))).encode()),
    }
    frames = (16_500_000 - len(head) - 64) // (len(row) + 1)
    cases["bvh 16.5 MB at Frame Time 0.001"] = (
        "big.bvh", (head + f"MOTION\nFrames: {frames}\nFrame Time: 0.001\n" + (row + "\n") * frames).encode())
    with server(args, log) as (base, _, pid):
        with Sampler(base, pid) as s:
            codes = {name: post_many(base, f"/v1/convert?filename={f}", [body], OCTETS)[0]
                     for name, (f, body) in cases.items()}
        idle = s.rss[0] if s.rss else rss_mb(pid)
    return {"codes": codes, "answers_500": sum(c >= 500 for c in codes.values()), "idle_mb": round(idle),
            "peak_mb": round(max(s.rss))}


def churn(args, log) -> dict:
    from websockets.sync.client import connect

    with server(args, log) as (base, port, _):
        url, loops, t = f"ws://{HOST}:{port}/v1/stream", 0, time.monotonic()
        while time.monotonic() - t < args.churn_s and loops < 100_000:
            with contextlib.suppress(Exception):
                with connect(url, open_timeout=5) as ws:
                    ws.send(json.dumps({"prompt": "a person walks", "seed": loops}))
            loops += 1
        time.sleep(2)
        streams = httpx.get(base + "/v1/health", timeout=10).json()["streams"]
    errors = [ln for ln in log.read_text(errors="replace").splitlines() if " ERROR " in ln]
    return {"loops": loops, "error_lines": len(errors), "windows": streams.get("windows"),
            "active_after": streams.get("active")}


ATTACKS = {"uploads": uploads, "idle_sockets": idle_sockets, "stopped_worker": stopped_worker,
           "heavy_then_light": heavy_then_light, "malformed_uploads": malformed, "stream_churn": churn}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--churn-s", type=float, default=10.0)
    p.add_argument("--only", action="append", choices=list(ATTACKS), default=None)
    args = p.parse_args()
    report = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only or ATTACKS:
            report[name] = ATTACKS[name](args, Path(tmp) / f"{name}.log")
            print(name, json.dumps(report[name]), file=sys.stderr, flush=True)
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
