"""`smf serve [--host 127.0.0.1] [--port 8000] [--checkpoint RUN] [--allow-host NAME]`: the HTTP API
(docs/serve.md)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub, name: str) -> None:
    from ..core.limits import BATCH_SIZE, ENGINES, PORTABLE_ENGINE
    from .flags import add_teacher_flag

    p = sub.add_parser(name,
                       description="An HTTP API (POST /v1/generate, GET /v1/health) with dynamic batching.")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                   help="a Host header name to accept besides localhost, 127.0.0.1 and ::1 (repeatable; needed "
                        "when clients reach the server by another name or address)")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="checkpoint or run folder (default: shipped model); with --engine onnx a folder of portable "
                        "graphs (smf export --onnx) or a model folder holding one")
    add_teacher_flag(p)
    p.add_argument("--adapter", type=Path, action="append", default=None,
                   help="an adapter file from `smf adapt`, served beside the model: requests name it with "
                        "\"adapter\" (repeatable)")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    p.add_argument("--engine", default="auto", choices=("auto",) + ENGINES + (PORTABLE_ENGINE,),
                   help=f"denoising engine of the worker (default auto: a torch engine where PyTorch is installed, "
                        f"else {PORTABLE_ENGINE}, the portable graphs on ONNX Runtime; 'compiled' pays on a CPU server: "
                        "a one-off compilation per shape, docs/inference.md)")
    p.add_argument("--max-batch", type=int, default=BATCH_SIZE, help="most requests in one sampling call")
    p.add_argument("--max-request-cost", type=float, default=None,
                   help="most work one request may ask for, in seconds x steps (default 2000: a 120 s timeline of "
                        "the shipped student with footskate loop; raise it on a faster machine; each queue lane holds four "
                        "requests' worth of work)")
    p.add_argument("--wait-ms", type=float, default=5.0, help="how long to gather requests for a batch (default 5)")
    p.add_argument("--max-queue", type=int, default=256, help="waiting requests before 503 (default 256)")
    p.add_argument("--threads", type=int, default=2,
                   help="threads of each generating process (torch or ONNX Runtime; default 2)")
    p.add_argument("--max-streams", type=int, default=None, metavar="N",
                   help="live streams at once on the WebSocket /v1/stream, made by a process of their own "
                        "(default 4; 0: no streams and no stream process)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import logging
    from dataclasses import replace

    from ..backends import backend_for
    from .options import check_adapter_flags

    if backend_for(None, args.engine) == "torch":
        check_adapter_flags(args)  # a crafted adapter file: one line, before anything heavy is imported
    import uvicorn

    from ..core.errors import SMFError
    from ..serve import ProcessWorker, create_app
    from ..serve.server_limits import MAX_STREAMS
    from ..serve.server import uvicorn_config
    from ..serve.live import StreamProcessWorker
    from .options import choose_engine

    if not 0 < args.port < 65536:
        raise SMFError(f"--port must be 1-65535, got {args.port}")
    if args.threads < 1:
        raise SMFError(f"--threads must be at least 1, got {args.threads}")
    max_streams = MAX_STREAMS if args.max_streams is None else args.max_streams
    if max_streams < 0:
        raise SMFError(f"--max-streams must be 0 or more, got {max_streams}")
    if args.max_request_cost is not None and not args.max_request_cost > 0:
        raise SMFError(f"--max-request-cost must be positive, got {args.max_request_cost}")
    cost = {} if args.max_request_cost is None else {"max_request_cost": args.max_request_cost}
    choose_engine(args, what="this engine")
    spec, model, adapters = worker_spec(args)  # checks the folder; the worker process loads the model itself
    streams = StreamProcessWorker(replace(spec, adapters=()), model) if max_streams else None  # the base model
    app = create_app(ProcessWorker(spec, model, adapters), max_batch=args.max_batch, wait_ms=args.wait_ms,
                     max_queue=args.max_queue, allowed_hosts=tuple(args.allow_host), streams=streams,
                     max_streams=max_streams, **cost)
    sock = listening_socket(args.host, args.port)  # a busy port is one line, before anything starts
    logging.basicConfig(level=logging.INFO, format="smf serve: %(levelname)s %(message)s")
    print(f"smf serve: http://{args.host}:{args.port} (POST /v1/generate, WebSocket /v1/stream, GET /v1/health; "
          "the model loads in the worker: /v1/health says when it is ready)", flush=True)
    uvicorn.Server(uvicorn_config(app, args.host, args.port)).run(sockets=[sock])


def worker_spec(args):
    """(WorkerSpec, ServedModel, adapter names) of the flags: the model folder checked and read, not loaded."""
    from ..backends import backend_for
    from ..serve.worker import ServedModel, WorkerSpec

    if backend_for(None, args.engine) == "onnx":  # its graphs load in a fraction of a second: read them here
        from ..pipelines.motion_pipeline import MotionPipeline

        model = ServedModel.of(MotionPipeline.from_pretrained(args.checkpoint, engine=args.engine,
                                                              teacher=args.teacher, adapter=args.adapter))
        folder = None if args.checkpoint is None else str(args.checkpoint)
        return WorkerSpec(folder, None, args.threads, args.engine, teacher=args.teacher), model, ()
    from ..diffusion.checkpoint import read_config
    from ..core.folders import model_folder

    checkpoint = model_folder(args.checkpoint, teacher=args.teacher)
    config = read_config(checkpoint)
    adapters = served_adapters(args.adapter or [], checkpoint)
    spec = WorkerSpec(str(checkpoint), args.device, args.threads, args.engine, tuple(str(a) for a in args.adapter or ()))
    return spec, ServedModel.from_config(config), adapters


def served_adapters(paths: list[Path], checkpoint: Path) -> tuple[str, ...]:
    """The names of the adapter files to serve, each checked against the model before the worker starts."""
    from ..adapters.file import checked_adapters

    return tuple(a.info.name for a in checked_adapters(paths, checkpoint))


def listening_socket(host: str, port: int):
    """A TCP socket bound to ``host``:``port``, or SMFError naming why not (a port in use, an unknown host)."""
    import errno
    import socket

    from ..core.errors import SMFError

    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except socket.gaierror as e:
        raise SMFError(f"cannot listen on {host}:{port}: {e.strerror}") from None
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
    except OSError as e:
        sock.close()
        hint = " (another server is using it: stop it or choose another --port)" if e.errno == errno.EADDRINUSE else ""
        raise SMFError(f"cannot listen on {host}:{port}: {e.strerror}{hint}") from None
    return sock
