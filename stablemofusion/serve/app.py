"""The HTTP API of `smf serve` (FastAPI): text to motion as JSON joints, BVH or .npy, with dynamic batching.

    POST /v1/generate[?format=json|bvh|npy]  {"prompt", "seconds"?, "seed"?, "guidance"?, "steps"?, "footskate"?}
    POST /v1/timeline[?format=...]           {"segments": [{"prompt", "seconds"}, ...], "seed"?, ...}
    POST /v1/convert?filename=NAME.bvh|.npy  (raw file bytes) -> the file's joints as JSON, for the viewer
    GET  /v1/health
    WS   /v1/stream                          a live stream: prompts in, frames out (serve/live.py)
    GET  /  the three.js viewer (assets/viewer, three.js vendored from npm: no CDN)

Every error is JSON ``{"error": "<one line>"}``: 4xx for bad input, 503 when the worker cannot answer, 500
for a request that failed in generation (the others of its batch are answered). Nothing uploaded is ever
unpickled. Layers: guard (headers, body) -> checks (input -> Job) -> batcher -> worker -> output.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import OrderedDict
from pathlib import Path

from fastapi import FastAPI, Request, WebSocket
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException

from .batcher import DynamicBatcher
from .checks import GenerateRequest, RequestChecks, TimelineRequest, check_format, parse_body, validation_message
from .convert import check_suffix, convert_upload
from .http_errors import ServeError, log_event
from .guard import Guard
from ..core import limits
from ..core.output import made_by
from .server_limits import (MAX_BODY_BYTES, MAX_REQUEST_COST, MAX_STREAMS, QUEUED_REQUESTS, RECENT_RESULTS,
                            UPLOAD_BUDGET_BYTES)
from .responses import motion_response, robot_response
from .live import StreamHub, ThreadStreamWorker, serve_stream
from .worker import Job, ThreadWorker

VIEWER = Path(__file__).resolve().parents[1] / "assets" / "viewer"


def error(status: int, message: str, retry_after: int | None = None) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status,
                        headers=None if retry_after is None else {"Retry-After": str(int(retry_after))})


async def _until_disconnected(request: Request) -> None:
    """Returns when the client has gone (the body was read by the guard: what follows is its disconnect)."""
    while (await request.receive())["type"] != "http.disconnect":
        pass


class RecentResults:
    """The last few motions made, by their job (its seed included, so the same job makes the same motion): the
    viewer asks for a motion as JSON and then as .glb, BVH or npy, and each later format is converted, not made
    again."""

    def __init__(self, size: int = RECENT_RESULTS):
        self.size, self._results = size, OrderedDict()

    def get(self, job: Job):
        result = self._results.get(job)
        if result is not None:
            self._results.move_to_end(job)
        return result

    def put(self, job: Job, result) -> None:
        self._results[job] = result
        self._results.move_to_end(job)
        while len(self._results) > self.size:
            self._results.popitem(last=False)


async def answer(request: Request, batcher: DynamicBatcher, job: Job, format: str,
                 recent: RecentResults | None = None, meta: dict | None = None, robot: str | None = None) -> Response:
    """Submit ``job`` (unless ``recent`` holds its motion) and answer with its motion in ``format`` (with ``meta``:
    what made it), or retargeted to ``robot``; a client that leaves cancels its job (it is dropped if it has not
    started)."""
    done = recent.get(job) if recent is not None else None
    if done is not None:
        return await _respond(done, format, meta, robot)
    work = asyncio.ensure_future(batcher.submit(job))
    gone = asyncio.ensure_future(_until_disconnected(request))
    try:
        await asyncio.wait({work, gone}, return_when=asyncio.FIRST_COMPLETED)
    except asyncio.CancelledError:  # the server is stopping: uvicorn cancels what outlives its graceful shutdown
        return error(503, "the server is shutting down; retry shortly")
    finally:
        gone.cancel()
        if not work.done():
            work.cancel()
    if not work.done() or work.cancelled():
        return error(499, "the client disconnected")
    result = work.result()  # a ServeError of the job propagates
    if recent is not None:
        recent.put(job, result)
    return await _respond(result, format, meta, robot)


async def _respond(result, format: str, meta: dict | None, robot: str | None) -> Response:
    if robot is None:
        return motion_response(result, format, meta)
    return await asyncio.to_thread(robot_response, result, robot, meta)  # MuJoCo work off the event loop


def _install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(ServeError)
    async def serve_error(request: Request, exc: ServeError):
        return error(exc.status, exc.message, exc.retry_after)

    @app.exception_handler(RequestValidationError)
    async def bad_request(request: Request, exc: RequestValidationError):
        return error(422, validation_message(exc.errors()))

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException):
        if exc.status_code == 404:
            return error(404, f"no such endpoint: {request.method} {request.url.path[:100]}")
        if exc.status_code == 405:
            return error(405, f"method {request.method} not allowed on {request.url.path[:100]}")
        return error(exc.status_code, str(exc.detail))

    @app.exception_handler(Exception)
    async def internal(request: Request, exc: Exception):
        log_event(logging.ERROR, "internal error on %s: %s: %s", request.url.path, type(exc).__name__, exc)
        return error(500, "internal server error")


def create_app(model, *, max_batch: int = limits.BATCH_SIZE, wait_ms: float = 5.0, max_queue: int = 256,
               max_body_bytes: int = MAX_BODY_BYTES, allowed_hosts: tuple[str, ...] = (), streams=None,
               max_streams: int = MAX_STREAMS, upload_budget: int = UPLOAD_BUDGET_BYTES,
               max_request_cost: float = MAX_REQUEST_COST, max_queued_cost: float | None = None) -> FastAPI:
    """The ASGI app; ``model`` is a worker (serve/worker.py: `smf serve` gives a supervised
    :class:`~stablemofusion.serve.worker.ProcessWorker`) or a pipeline (generated on a thread). ``streams``
    the live streams' worker (serve/live.py; default: a thread with ``model`` when it is a pipeline, else
    none); ``max_streams`` live streams at once (0: none); ``max_request_cost`` the most work one request may ask for
    (422 beyond), ``max_queued_cost`` the most work waiting in a lane (503 with Retry-After beyond; default
    ``QUEUED_REQUESTS`` requests of ``max_request_cost``)."""
    worker = model if hasattr(model, "submit") else ThreadWorker(model)
    if streams is None and not hasattr(model, "submit") and max_streams > 0:
        streams = ThreadStreamWorker(model, worker.executor)
    hub = StreamHub(streams, max_streams if streams is not None else 0)
    if max_queued_cost is None:
        max_queued_cost = QUEUED_REQUESTS * max_request_cost
    batcher = DynamicBatcher(worker, max_batch=max_batch, wait_ms=wait_ms, max_queue=max_queue,
                             max_queued_cost=max_queued_cost, max_batch_cost=max_request_cost)
    cfg = worker.model
    checks = RequestChecks(cfg, max_request_cost, getattr(worker, "adapters", ()))
    recent = RecentResults()
    made = made_by(cfg.version)  # what every answer says made it
    converting = asyncio.Semaphore(1)  # one upload parsed at a time, on a thread

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        worker.start()
        if streams is not None:
            streams.start()
        yield
        batcher.close()
        hub.stop()
        worker.close()
        if streams is not None:
            streams.close()

    app = FastAPI(title="stablemofusion", summary="Text to human motion", docs_url=None, redoc_url=None,
                  openapi_url=None, lifespan=lifespan)
    app.state.batcher, app.state.worker, app.state.streams = batcher, worker, hub
    app.add_middleware(Guard, max_body_bytes=max_body_bytes, allowed_hosts=tuple(allowed_hosts),
                       upload_budget=upload_budget)
    _install_error_handlers(app)

    @app.get("/v1/health")
    async def health() -> JSONResponse:
        state = worker.health()
        ready = state["state"] == "ready"
        sizes = batcher.batch_sizes
        return JSONResponse(
            {"status": "ok" if ready else state["state"], "worker": state, "fps": cfg.fps,
             "seconds": [cfg.min_frames / cfg.fps, limits.MAX_SECONDS],
             "limits": {**limits.table(), "footskate": list(cfg.footskate)},
             "max_batch": max_batch, **made, "waiting": batcher.waiting, "queue": batcher.queue_state(),
             "adapters": list(checks.adapters),
             "batches": len(sizes), "largest_batch": max(sizes, default=0), "dropped": batcher.dropped,
             "streams": hub.health() if streams is not None else {"state": "off", "active": 0, "max": 0}},
            status_code=200 if ready else 503)

    @app.post("/v1/generate")
    async def generate(request: Request, format: str = "json"):
        check_format(format)
        body = parse_body(await request.body(), GenerateRequest)
        if body.robot is not None and format != "json":
            raise ServeError(422, f"robot: a robot's trajectory is answered as JSON, not {format}")
        job = checks.generate(body)
        return await answer(request, batcher, job, format, recent, made, body.robot)

    @app.post("/v1/timeline")
    async def timeline(request: Request, format: str = "json"):
        check_format(format)
        job = checks.timeline(parse_body(await request.body(), TimelineRequest))
        return await answer(request, batcher, job, format, recent, made)

    @app.post("/v1/convert")
    async def convert(request: Request, filename: str):
        check_suffix(filename)
        data = await request.body()
        async with converting:
            payload = await asyncio.to_thread(convert_upload, data, filename)
        return Response(payload, media_type="application/json")

    @app.websocket("/v1/stream")
    async def stream(ws: WebSocket):
        await serve_stream(ws, hub, cfg.fps)

    @app.get("/", include_in_schema=False)
    async def viewer():
        return FileResponse(VIEWER / "index.html")

    app.mount("/viewer", StaticFiles(directory=VIEWER), name="viewer")
    return app
