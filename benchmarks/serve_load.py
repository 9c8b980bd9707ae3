"""Load test of `smf serve` on this machine: N concurrent requests against the same N sent one by one.

Starts the server (shipped model unless --checkpoint) as a subprocess on a free loopback port, waits for
/v1/health, then sends the requests (distinct seeds and prompts, --seconds long) all at once with aiohttp, and
again one at a time; prints JSON: errors, wall time, throughput (requests/s), p50/p99 latency, and the
batch sizes the server formed. Loopback only; the server is stopped at the end.

    python benchmarks/serve_load.py --requests 200 [--seconds 4] [--footskate off] [--no-one-by-one]

With --reference, the pipeline's own batch-32 end-to-end throughput (one process, the same threads, text
cached, motions/s; one warm-up call, best of 3) is measured first and the server's concurrent throughput is
reported as a ratio of it. Both are warmed the same way: the server gets one untimed concurrent pass of the
same requests (its worker's first batches, the client's connections), then --passes timed ones (best reported,
all listed).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys
import time

import aiohttp
import httpx
import numpy as np
import orjson

PROMPTS = ["a person walks forward", "a tired man shuffles forward", "someone waves both hands",
           "a person runs in a circle", "a proud soldier marches", "an old woman bows", "a child kicks",
           "a person raises the right hand"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def summary(latencies: list[float], wall: float, errors: int) -> dict:
    lat = np.asarray(latencies) * 1000
    return {"requests": len(latencies) + errors, "errors": errors, "wall_s": round(wall, 2),
            "throughput_rps": round(len(latencies) / wall, 2),
            "p50_ms": round(float(np.percentile(lat, 50)), 1), "p99_ms": round(float(np.percentile(lat, 99)), 1)}


async def one(session: aiohttp.ClientSession, base: str, body: dict) -> tuple[float, bool]:
    t = time.perf_counter()
    async with session.post(base + "/v1/generate", json=body) as r:
        data = await r.read()
        ok = r.status == 200 and len(orjson.loads(data)["joints"]) > 0
    return time.perf_counter() - t, ok


def pipeline_reference(args, bodies: list[dict], batch: int = 32, repeats: int = 3) -> float:
    """Motions/s of the pipeline itself on batches of ``batch`` of the same requests (best of ``repeats``)."""
    import torch

    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    torch.set_num_threads(args.threads)
    pipe = MotionPipeline.from_pretrained(args.checkpoint, device="cpu")
    items = bodies[:batch]
    call = lambda: pipe([b["prompt"] for b in items], seconds=args.seconds, seed=[b["seed"] for b in items],  # noqa: E731
                        footskate=args.footskate, batch_size=batch)
    call()  # warm-up: text cache
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - t)
    return len(items) / best


async def concurrent_pass(session: aiohttp.ClientSession, base: str, bodies: list[dict]) -> dict:
    """All ``bodies`` sent at once; the summary of their answers."""
    t = time.perf_counter()
    out = await asyncio.gather(*[one(session, base, b) for b in bodies])
    return summary([d for d, ok in out if ok], time.perf_counter() - t, sum(not ok for _, ok in out))


async def run(base: str, bodies: list[dict], one_by_one: bool = True, passes: int = 1) -> dict:
    """The load, from an aiohttp client (keep-alive, one connection per request in flight): httpx's async
    pool was the bottleneck at 200 concurrent requests (44-300 requests/s against a server whose generation
    is instant, vs about 1,000 with aiohttp)."""
    async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0)) as session:
        await concurrent_pass(session, base, bodies)  # warm-up, untimed
        # each pass its own seeds: the server keeps its last motions by request, and must not answer from them
        runs = [await concurrent_pass(session, base, [{**b, "seed": b["seed"] + (k + 1) * len(bodies)} for b in bodies])
                for k in range(passes)]
        concurrent = {**max(runs, key=lambda r: r["throughput_rps"]),
                      "passes_rps": [r["throughput_rps"] for r in runs]}
        async with session.get(base + "/v1/health") as r:
            health = await r.json()
        if not one_by_one:
            return {"concurrent": concurrent, "health": health}
        t = time.perf_counter()
        seq = [await one(session, base, b) for b in bodies]
        sequential = summary([d for d, ok in seq if ok], time.perf_counter() - t, sum(not ok for _, ok in seq))
    return {"concurrent": concurrent, "one_by_one": sequential,
            "speed_up": round(concurrent["throughput_rps"] / sequential["throughput_rps"], 2), "health": health}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--requests", type=int, default=200)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--footskate", default="off")
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--threads", type=int, default=2, help="torch threads of the server (default 2)")
    ap.add_argument("--no-one-by-one", action="store_true", help="skip the one-by-one pass")
    ap.add_argument("--reference", action="store_true", help="measure the pipeline's own batch-32 throughput first")
    ap.add_argument("--passes", type=int, default=3, help="timed concurrent passes after the warm-up (best reported)")
    args = ap.parse_args()
    bodies = [{"prompt": PROMPTS[i % len(PROMPTS)], "seconds": args.seconds, "seed": i, "footskate": args.footskate}
              for i in range(args.requests)]
    reference = pipeline_reference(args, bodies) if args.reference else None
    port = free_port()
    cmd = [sys.executable, "-m", "stablemofusion.cli.main", "serve", "--port", str(port), "--device", "cpu",
           "--threads", str(args.threads)]
    if args.checkpoint:
        cmd += ["--checkpoint", args.checkpoint]
    env = {**os.environ, "OMP_NUM_THREADS": str(args.threads)}
    server = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(600):
            try:
                if httpx.get(base + "/v1/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.2)  # 503 while the worker loads and warms
        else:
            raise SystemExit("server did not start: " + server.stderr.read().decode()[-500:])
        warm = {"prompt": PROMPTS[0], "seconds": args.seconds, "seed": 0, "footskate": args.footskate}
        httpx.post(base + "/v1/generate", json=warm, timeout=600)  # text encoder, first forward, torch.optim
        report = asyncio.run(run(base, bodies, not args.no_one_by_one, args.passes))
        report.update({"seconds": args.seconds, "footskate": args.footskate, "server_threads": args.threads})
        if reference is not None:
            report["pipeline_batch32_motions_per_s"] = round(reference, 2)
            report["ratio"] = round(report["concurrent"]["throughput_rps"] / reference, 3)
        print(json.dumps(report, indent=1))
    finally:
        server.terminate()
        server.wait(10)


if __name__ == "__main__":
    main()
