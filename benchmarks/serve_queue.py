"""A light request behind many heavy ones, on the portable runtime's server (`smf serve --engine onnx`, in process on
127.0.0.1): N heavy requests (120 s motions) sent at once, then one light request (4 s); prints each answer's status
and time, the light request's latency, and what health said meanwhile.

    python benchmarks/serve_queue.py [--heavy 64]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "serve"))
from serve_helpers import live_server  # noqa: E402

from stablemofusion.pipelines.motion_pipeline import MotionPipeline  # noqa: E402
from stablemofusion.serve.app import create_app  # noqa: E402


async def run(base: str, heavy: int) -> dict:
    async with httpx.AsyncClient(base_url=base, timeout=600) as client:
        async def post(body):
            t = time.perf_counter()
            r = await client.post("/v1/generate", json=body)
            return r.status_code, time.perf_counter() - t, r.headers.get("retry-after")

        heavy_jobs = [asyncio.ensure_future(post({"prompt": "a person walks forward", "seconds": 120, "seed": i}))
                      for i in range(heavy)]
        await asyncio.sleep(0.5)
        h = (await client.get("/v1/health")).json()
        health = h.get("queue", {"waiting": h.get("waiting")})
        light = await post({"prompt": "a person waves both hands", "seconds": 4, "seed": 1})
        done = await asyncio.gather(*heavy_jobs)
    codes = [c for c, _, _ in done]
    return {"heavy": heavy, "heavy_200": codes.count(200), "heavy_503": codes.count(503),
            "heavy_503_with_retry_after": sum(1 for c, _, ra in done if c == 503 and ra),
            "slowest_503_s": round(max((t for c, t, _ in done if c == 503), default=0), 3),
            "last_heavy_200_s": round(max((t for c, t, _ in done if c == 200), default=0), 2),
            "light_status": light[0], "light_s": round(light[1], 2), "health_queue_while_busy": health}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--heavy", type=int, default=64)
    args = ap.parse_args()
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    with live_server(create_app(pipe, max_streams=0)) as base:
        print(json.dumps(asyncio.run(run(base, args.heavy)), indent=1))


if __name__ == "__main__":
    main()
