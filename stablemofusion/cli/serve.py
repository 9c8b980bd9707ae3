"""`smf serve [--host 127.0.0.1] [--port 8000] [--checkpoint RUN]`: the HTTP API (docs/serve.md)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub, name: str) -> None:
    from ..diffusion.engine import ENGINES

    p = sub.add_parser(name, help="serve text-to-motion over HTTP",
                       description="An HTTP API (POST /v1/generate, GET /v1/health) with dynamic batching.")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--checkpoint", type=Path, default=None, help="checkpoint or run folder (default: shipped model)")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    p.add_argument("--engine", default="auto", choices=("auto",) + ENGINES,
                   help="denoising engine of the worker (default auto; 'compiled' pays on a CPU server: a one-off "
                        "compilation per shape, docs/inference.md)")
    p.add_argument("--max-batch", type=int, default=32, help="most requests in one sampling call (default 32)")
    p.add_argument("--wait-ms", type=float, default=5.0, help="how long to gather requests for a batch (default 5)")
    p.add_argument("--max-queue", type=int, default=256, help="waiting requests before 503 (default 256)")
    p.add_argument("--threads", type=int, default=2, help="torch threads of the generating process (default 2)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import uvicorn

    from ..errors import SMFError
    from ..pipeline import MotionPipeline
    from ..serve import create_app
    from ..serve.batcher import process_executor

    if not 0 < args.port < 65536:
        raise SMFError(f"--port must be 1-65535, got {args.port}")
    if args.threads < 1:
        raise SMFError(f"--threads must be at least 1, got {args.threads}")
    pipe = MotionPipeline.from_pretrained(args.checkpoint, device=args.device, engine=args.engine)  # checks it
    checkpoint = None if args.checkpoint is None else str(args.checkpoint)
    # generation runs in a worker process, off the event loop's GIL
    executor = process_executor(checkpoint, args.device, args.threads, args.engine)
    app = create_app(pipe, max_batch=args.max_batch, wait_ms=args.wait_ms, max_queue=args.max_queue,
                     executor=executor)
    print(f"smf serve: http://{args.host}:{args.port} (POST /v1/generate, GET /v1/health)", flush=True)
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning")
