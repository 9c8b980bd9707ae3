"""Fault injection against `smf serve`: normal requests keep being answered, right, while hostile clients
attack and the generation worker is killed once.

Starts `smf serve` on 127.0.0.1 only (a free port; the shipped model unless --checkpoint), waits until
/v1/health is ready, and then, at the same time:
- sends N normal /v1/generate requests (distinct seeds, 4 s, at most --concurrency at once);
- sends every hostile case of tests/serve/test_hardening.py (each must get a 4xx), opens half-open connections
  (the server must close them) and abandons long timelines (the server must drop them before they run);
- kills the worker process (SIGKILL) once, after a quarter of the normal requests are answered;
- samples /v1/health (its answer must match the worker: 200 only while the worker process is alive and
  ready) and the resident memory of the server and all its child processes (never above 1.5x idle).
A normal request answered 503 (in flight when the worker died, or a full queue) is retried (at most
--retries times, one second apart); it counts as lost if no try gets a 200. Afterwards every normal request
is sent again with no faults: an answer that differs (joints more than 1e-4 m apart) counts as wrong.
Every loop is bounded in count and time. Prints one JSON report.

    python benchmarks/serve_faults.py [--requests 200] [--concurrency 8] [--checkpoint RUN]
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

HOST = "127.0.0.1"  # never any other address
PROMPTS = ["a person walks forward", "a tired man shuffles forward", "someone waves both hands",
           "a person runs in a circle", "a proud soldier marches", "an old woman bows", "a child kicks",
           "a person raises the right hand"]
JSON_CT = {"Content-Type": "application/json"}
OCTETS = {"Content-Type": "application/octet-stream"}
START_TIMEOUT_S = 300.0
REQUEST_TIMEOUT_S = 300.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def rss_mb(pid: int) -> float:
    """Resident memory of ``pid`` and all its descendants (MB)."""
    total, todo, seen = 0, [pid], set()
    while todo and len(seen) < 64:
        p = todo.pop()
        seen.add(p)
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
            for task in Path(f"/proc/{p}/task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            continue
    return total / 1024


def alive(pid: int | None) -> bool:
    try:
        return pid is not None and Path(f"/proc/{pid}/stat").read_text().split(") ", 1)[1][0] != "Z"
    except OSError:
        return False


def bvh_cases() -> dict[str, bytes]:
    from stablemofusion.motion.files import load_motion, save_bvh

    with tempfile.TemporaryDirectory() as tmp:
        save_bvh(load_motion("example:wave-both-hands").joints[:2], Path(tmp) / "w.bvh")
        text = (Path(tmp) / "w.bvh").read_text()
    last = text.rstrip("\n").rsplit("\n", 1)[1]
    return {"bvh Frame Time 10000": text.replace("Frame Time: 0.05", "Frame Time: 10000"),
            "bvh Frame Time 1e9": text.replace("Frame Time: 0.05", "Frame Time: 1e9"),
            "bvh CHANNELS inf": text.replace("CHANNELS 3", "CHANNELS inf", 1),
            "bvh OFFSET nan": text.replace("OFFSET 0.000000 0.000000 0.000000", "OFFSET nan 0 0", 1),
            "bvh values 1e305": text.replace(last, " ".join(["1e305"] * len(last.split())))}


def hostile_http() -> list[tuple[str, str, str, bytes, dict]]:
    """(name, method, url, body, headers) of every hostile HTTP request."""
    npy = io.BytesIO()
    np.save(npy, np.zeros((15_000_000 // 66, 22, 3), np.int8))
    cases = [
        ("prompt with a lone surrogate", "POST", "/v1/generate", b'{"prompt": "walk \\ud800"}', JSON_CT),
        ("timeline with a 1e-9 s segment", "POST", "/v1/timeline",
         b'{"segments": [{"prompt": "walk", "seconds": 3}, {"prompt": "wave", "seconds": 1e-9}]}', JSON_CT),
        ('{"seed": true}', "POST", "/v1/generate", b'{"prompt": "walk", "seed": true}', JSON_CT),
        ('"seconds": "4"', "POST", "/v1/generate", b'{"prompt": "walk", "seconds": "4"}', JSON_CT),
        ("body not UTF-8", "POST", "/v1/generate", b'{"prompt": "walk \xff\xfe"}', JSON_CT),
        ("JSON body of 20 kB", "POST", "/v1/generate", json.dumps({"prompt": "x" * 20000}).encode(), JSON_CT),
        ("generate as text/plain (no preflight)", "POST", "/v1/generate", b'{"prompt": "walk"}',
         {"Content-Type": "text/plain"}),
        ("convert as text/plain (no preflight)", "POST", "/v1/convert?filename=a.bvh", b"HIERARCHY",
         {"Content-Type": "text/plain"}),
        ("Host: evil.example (DNS rebinding)", "GET", "/v1/health", b"", {"Host": "evil.example"}),
        ("npy of 15 MB int8", "POST", "/v1/convert?filename=m.npy", npy.getvalue(), OCTETS),
    ]
    cases += [(name, "POST", "/v1/convert?filename=w.bvh", text.encode(), OCTETS) for name, text in bvh_cases().items()]
    return cases


def raw_exchange(port: int, head: bytes, body_chunks, limit_s: float = 30.0) -> int | None:
    """Send ``head`` then chunks (stopping when the server answers or closes); the status code, or None."""
    with socket.create_connection((HOST, port), timeout=limit_s) as s:
        s.sendall(head)
        s.setblocking(False)
        deadline, reply = time.monotonic() + limit_s, b""
        for chunk in body_chunks:
            if time.monotonic() > deadline:
                break
            try:
                reply += s.recv(4096)
                if reply:
                    break
            except BlockingIOError:
                pass
            try:
                s.sendall(chunk)
            except (BlockingIOError, BrokenPipeError, ConnectionResetError):
                break
        s.setblocking(True)
        s.settimeout(limit_s)
        try:
            while b"\r\n" not in reply:
                more = s.recv(4096)
                if not more:
                    break
                reply += more
        except OSError:
            pass
    try:
        return int(reply.split(b" ", 2)[1])
    except (IndexError, ValueError):
        return None


def chunked_400mb(port: int) -> int | None:
    head = (f"POST /v1/generate HTTP/1.1\r\nHost: {HOST}:{port}\r\nContent-Type: application/json\r\n"
            "Transfer-Encoding: chunked\r\n\r\n").encode()
    chunk = b"10000\r\n" + b"x" * 65536 + b"\r\n"
    return raw_exchange(port, head, (chunk for _ in range(400 * 16)))  # 400 MB if the server read it all


def length_and_chunked(port: int) -> int | None:
    head = (f"POST /v1/generate HTTP/1.1\r\nHost: {HOST}:{port}\r\nContent-Type: application/json\r\n"
            "Content-Length: 5\r\nTransfer-Encoding: chunked\r\n\r\n").encode()
    return raw_exchange(port, head, iter([b"5\r\n{\"a\":\r\n0\r\n\r\n"]))


def half_open(port: int, n: int, limit_s: float) -> tuple[int, float]:
    """Open ``n`` connections that never finish their headers; how many the server closed, and when."""
    socks = []
    for _ in range(n):
        s = socket.create_connection((HOST, port), timeout=limit_s)
        s.sendall(b"GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        socks.append(s)
    t0, closed = time.monotonic(), 0
    for s in socks:
        try:
            s.settimeout(max(0.1, limit_s - (time.monotonic() - t0)))
            closed += s.recv(100) == b""
        except OSError:
            pass
        finally:
            s.close()
    return closed, time.monotonic() - t0


class Run:
    def __init__(self, base: str, port: int, server_pid: int, args):
        self.base, self.port, self.server_pid, self.args = base, port, server_pid, args
        self.health: list[dict] = []
        self.memory: list[float] = []
        self.stop = asyncio.Event()
        self.answered = 0
        self.kill: dict = {}

    async def sample_health(self, client: httpx.AsyncClient) -> None:
        for _ in range(int(self.args.max_minutes * 60 / 0.2)):
            if self.stop.is_set():
                return
            t = time.perf_counter()
            try:
                r = await client.get("/v1/health", timeout=10)
                body, code = r.json(), r.status_code
            except httpx.HTTPError as e:
                body, code = {"worker": {}, "status": type(e).__name__}, None
            w = body.get("worker", {})
            honest = (code == 200) == (w.get("state") == "ready" and alive(w.get("pid")) and bool(w.get("warm")))
            self.health.append({"t": time.perf_counter(), "latency": time.perf_counter() - t, "code": code,
                                "status": body.get("status"), "honest": honest, "dropped": body.get("dropped")})
            await asyncio.sleep(0.2)

    async def sample_memory(self) -> None:
        for _ in range(int(self.args.max_minutes * 60 / 0.1)):
            if self.stop.is_set():
                return
            self.memory.append(rss_mb(self.server_pid))
            await asyncio.sleep(0.1)

    async def normal(self, client: httpx.AsyncClient, body: dict, gate: asyncio.Semaphore) -> dict:
        async with gate:
            tries = []
            for _ in range(1 + self.args.retries):
                try:
                    r = await client.post("/v1/generate", json=body, timeout=REQUEST_TIMEOUT_S)
                    tries.append(r.status_code)
                except httpx.HTTPError as e:
                    tries.append(type(e).__name__)
                    r = None
                if tries[-1] != 503:
                    break
                await asyncio.sleep(1.0)
            self.answered += 1
            joints = np.asarray(r.json()["joints"]) if r is not None and r.status_code == 200 else None
            ok = joints is not None and joints.shape == (80, 22, 3) and r.json()["seed"] == body["seed"]
            return {"tries": tries, "ok": ok, "joints": joints}

    async def kill_worker(self, client: httpx.AsyncClient) -> None:
        for _ in range(int(self.args.max_minutes * 600)):
            if self.answered >= self.args.requests // 4:
                break
            await asyncio.sleep(0.1)
        pid = (await client.get("/v1/health")).json()["worker"]["pid"]
        os.kill(pid, signal.SIGKILL)
        t0 = time.perf_counter()
        for _ in range(int(START_TIMEOUT_S / 0.2)):
            await asyncio.sleep(0.2)
            r = await client.get("/v1/health")
            if r.status_code == 200 and r.json()["worker"]["pid"] != pid:
                break
        self.kill = {"killed_pid": pid, "ready_again_after_s": round(time.perf_counter() - t0, 1),
                     "restarts": r.json()["worker"]["restarts"]}

    async def hostile(self, client: httpx.AsyncClient) -> dict:
        out = {}
        for name, method, url, body, headers in hostile_http():
            r = await client.request(method, url, content=body, headers=headers, timeout=60)
            out[name] = r.status_code
            await asyncio.sleep(0.3)
        out["chunked body of 400 MB"] = await asyncio.to_thread(chunked_400mb, self.port)
        out["Content-Length with Transfer-Encoding: chunked"] = await asyncio.to_thread(length_and_chunked, self.port)
        return out

    async def abandon_timelines(self) -> int:
        """Three clients ask for 120 s timelines and leave after half a second."""
        body = {"segments": [{"prompt": "a person walks", "seconds": 60}, {"prompt": "a person runs", "seconds": 60}]}
        left = 0
        for _ in range(3):
            async with httpx.AsyncClient(base_url=self.base) as client:
                try:
                    await client.post("/v1/timeline", json=body, timeout=0.5)
                except httpx.TimeoutException:
                    left += 1
        return left


async def main_async(base: str, port: int, server_pid: int, args) -> dict:
    run = Run(base, port, server_pid, args)
    bodies = [{"prompt": PROMPTS[i % len(PROMPTS)], "seconds": 4.0, "seed": 1000 + i} for i in range(args.requests)]
    limits = httpx.Limits(max_connections=args.concurrency + 16)
    async with httpx.AsyncClient(base_url=base, limits=limits, timeout=REQUEST_TIMEOUT_S) as client:
        await client.post("/v1/generate", json=bodies[0])  # warm the server's side too
        idle = []
        for _ in range(10):
            await asyncio.sleep(0.1)
            idle.append(rss_mb(server_pid))
        idle_mb = float(np.median(idle))
        samplers = [asyncio.ensure_future(run.sample_health(client)), asyncio.ensure_future(run.sample_memory())]
        gate = asyncio.Semaphore(args.concurrency)
        t0 = time.perf_counter()
        normal = asyncio.gather(*[run.normal(client, b, gate) for b in bodies])
        log_prompt = client.post("/v1/generate", json={"prompt": "does a backflip \x1b[2J\x1b[31m\x00", "seconds": 2})
        hostile, _, left, (closed, closed_s), logged, results = await asyncio.gather(
            run.hostile(client), run.kill_worker(client), run.abandon_timelines(),
            asyncio.to_thread(half_open, port, 50, 30.0), log_prompt, normal)
        wall = time.perf_counter() - t0
        run.stop.set()
        await asyncio.gather(*samplers)
        # the same requests again, no faults: every answer must be the same motion
        check = await asyncio.gather(*[run.normal(client, b, gate) for b in bodies])
        final = (await client.get("/v1/health")).json()
    diffs = [float(np.abs(a["joints"] - b["joints"]).max()) if a["ok"] and b["ok"] and
             a["joints"].shape == b["joints"].shape else float("inf") for a, b in zip(results, check) if a["ok"]]
    wrong = sum(not d < 1e-4 for d in diffs)
    return {
        "normal": {"sent": len(results), "ok_first_try": sum(r["ok"] and len(r["tries"]) == 1 for r in results),
                   "answered_503_then_ok_on_retry": sum(r["ok"] and len(r["tries"]) > 1 for r in results),
                   "lost": sum(not r["ok"] for r in results), "wrong": wrong,
                   "largest_joint_difference_m": max(diffs, default=0.0), "wall_s": round(wall, 1),
                   "statuses_of_lost": [r["tries"] for r in results if not r["ok"]][:10]},
        "hostile": {"cases": len(hostile), "all_4xx": all(c is not None and 400 <= c < 500 for c in hostile.values()),
                    "status": hostile},
        "prompt with ANSI escapes and NUL": logged.status_code,
        "half_open_connections": {"opened": 50, "closed_by_server": closed, "within_s": round(closed_s, 1)},
        "abandoned_timelines": {"clients_left": left, "dropped_before_running": final["dropped"]},
        "worker_kill": run.kill,
        "memory_mb": {"idle": round(idle_mb), "peak": round(max(run.memory)), "peak_over_idle":
                      round(max(run.memory) / idle_mb, 2), "samples": len(run.memory)},
        "health": {"samples": len(run.health), "dishonest": sum(not h["honest"] for h in run.health),
                   "not_ready_samples": sum(h["code"] != 200 for h in run.health),
                   "max_latency_ms": round(1000 * max(h["latency"] for h in run.health)),
                   "states_seen": sorted({str(h["status"]) for h in run.health})},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--requests", type=int, default=200)
    ap.add_argument("--concurrency", type=int, default=8)
    ap.add_argument("--retries", type=int, default=3)
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--threads", type=int, default=1, help="torch threads of the worker (default 1)")
    ap.add_argument("--max-minutes", type=float, default=20.0, help="bound of every sampling loop")
    args = ap.parse_args()
    port = free_port()
    cmd = [sys.executable, "-m", "stablemofusion.cli.main", "serve", "--host", HOST, "--port", str(port),
           "--device", "cpu", "--threads", str(args.threads)] + (["--checkpoint", args.checkpoint] if args.checkpoint
                                                                 else [])
    env = {**os.environ, "OMP_NUM_THREADS": str(args.threads)}
    log = tempfile.TemporaryFile()
    server = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=log)
    base = f"http://{HOST}:{port}"
    try:
        for _ in range(int(START_TIMEOUT_S / 0.5)):
            try:
                if httpx.get(base + "/v1/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.5)
        else:
            raise SystemExit("the server did not become ready")
        report = asyncio.run(main_async(base, port, server.pid, args))
    finally:
        server.send_signal(signal.SIGTERM)
        t0 = time.perf_counter()
        server.wait(30)
        stopped_s = time.perf_counter() - t0
    log.seek(0)
    text = log.read()
    report["server_log"] = {"bytes": len(text), "raw_ESC_or_NUL": text.count(b"\x1b") + text.count(b"\x00"),
                            "escaped_prompt_logged": b"\\x1b[2J" in text}
    report["sigterm_exit_s"] = round(stopped_s, 1)
    report["command"] = " ".join(["python benchmarks/serve_faults.py"] + sys.argv[1:])
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
