"""The HTTP API of `smf serve` (FastAPI): text to motion as JSON joints, BVH or .npy, with dynamic batching.

    POST /v1/generate[?format=json|bvh|npy]  {"prompt", "seconds"?, "seed"?, "guidance"?, "steps"?, "footskate"?}
    POST /v1/convert?filename=NAME.bvh|.npy  (raw file bytes) -> the file's joints as JSON, for the viewer
    GET  /v1/health
    GET  /  the three.js viewer (assets/viewer, three.js vendored from npm: no CDN)

Bad input gets a 4xx JSON ``{"error": "<one line>"}``; a full queue 503. Nothing uploaded is ever unpickled.
"""

from __future__ import annotations

import contextlib
import io
import random
import tempfile
from pathlib import Path
from typing import Literal

import numpy as np
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field

from ..errors import SMFError
from .batcher import DynamicBatcher, Job, QueueFull

MAX_PROMPT_CHARS = 300
MAX_BODY_BYTES = 16 * 1024
MAX_UPLOAD_BYTES = 16 * 1024 * 1024  # a dropped .bvh / .npy
VIEWER = Path(__file__).resolve().parents[1] / "assets" / "viewer"
MAX_STEPS = 50
FORMATS = ("json", "bvh", "npy")
MAX_SEGMENTS = 16
MAX_TIMELINE_SECONDS = 120.0


class GenerateRequest(BaseModel):
    """The body of POST /v1/generate."""

    model_config = ConfigDict(extra="forbid")

    prompt: str
    seconds: float | None = None  # None: predicted from the text (models with a length estimator), else 4 s
    seed: int | None = Field(default=None, ge=0, lt=2**63)
    guidance: float = Field(default=2.5, ge=0.0, le=20.0)
    steps: int = Field(default=10, ge=1, le=MAX_STEPS)
    footskate: Literal["off", "post", "loop"] = "off"


class Segment(BaseModel):
    """One entry of a timeline: what to do and for how long."""

    model_config = ConfigDict(extra="forbid")

    prompt: str
    seconds: float = Field(gt=0.0)


class TimelineRequest(BaseModel):
    """The body of POST /v1/timeline: one continuous motion from several prompts."""

    model_config = ConfigDict(extra="forbid")

    segments: list[Segment] = Field(min_length=1, max_length=MAX_SEGMENTS)
    seed: int | None = Field(default=None, ge=0, lt=2**63)
    guidance: float = Field(default=2.5, ge=0.0, le=20.0)
    steps: int = Field(default=10, ge=1, le=MAX_STEPS)
    footskate: Literal["off", "post", "loop"] = "off"


def _motion_response(r, seed: int, format: str) -> Response:
    """A generated motion as JSON (joints), a BVH file or a joints .npy."""
    if format == "npy":
        buf = io.BytesIO()
        np.save(buf, r.joints.astype(np.float32), allow_pickle=False)
        return Response(buf.getvalue(), media_type="application/octet-stream",
                        headers={"Content-Disposition": 'attachment; filename="motion_joints.npy"'})
    if format == "bvh":
        return Response(_bvh_text(r), media_type="text/plain; charset=utf-8",
                        headers={"Content-Disposition": 'attachment; filename="motion.bvh"'})
    # JSONResponse serialises with json.dumps (C); FastAPI's own encoder walks every float in Python and,
    # on the event loop, starved the batching of requests arriving meanwhile
    return JSONResponse({"prompt": r.prompt, "fps": r.fps, "frames": len(r.joints), "seed": seed,
                         **(r.domain.to_dict(r.prompt) if r.domain else {}),
                         "joints": np.round(r.joints, 5).tolist()})


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


def _validation_message(exc: RequestValidationError) -> str:
    first = exc.errors()[0] if exc.errors() else {}
    if first.get("type") == "json_invalid":
        return "body: not valid JSON"
    where = ".".join(str(p) for p in first.get("loc", ()) if p != "body") or "body"
    return f"{where}: {first.get('msg', 'invalid request')}".replace("\n", " ")


def create_app(pipe, *, max_batch: int = 32, wait_ms: float = 5.0, max_queue: int = 256,
               max_body_bytes: int = MAX_BODY_BYTES, executor=None) -> FastAPI:
    """The ASGI app serving ``pipe`` (a :class:`~stablemofusion.pipeline.MotionPipeline`); ``executor`` where
    generation runs (default a thread over ``pipe``; `smf serve` uses a worker process loading the same model)."""
    batcher = DynamicBatcher(pipe, max_batch=max_batch, wait_ms=wait_ms, max_queue=max_queue, executor=executor)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        yield
        batcher.close()

    app = FastAPI(title="stablemofusion", summary="Text to human motion", docs_url=None, redoc_url=None,
                  lifespan=lifespan)
    app.state.batcher = batcher
    min_s, max_s = pipe.min_frames / pipe.fps, pipe.max_frames / pipe.fps

    @app.middleware("http")
    async def limit_body(request: Request, call_next):
        limit = MAX_UPLOAD_BYTES if request.url.path == "/v1/convert" else max_body_bytes
        size = request.headers.get("content-length")
        if size is not None and (not size.isdigit() or int(size) > limit):
            return _error(413, f"request body larger than {limit} bytes")
        return await call_next(request)

    @app.exception_handler(RequestValidationError)
    async def bad_request(request: Request, exc: RequestValidationError):
        return _error(422, _validation_message(exc))

    @app.exception_handler(404)
    async def not_found(request: Request, exc):
        return _error(404, f"no such endpoint: {request.method} {request.url.path}")

    @app.exception_handler(405)
    async def bad_method(request: Request, exc):
        return _error(405, f"method {request.method} not allowed on {request.url.path}")

    @app.get("/v1/health")
    async def health() -> dict:
        sizes = batcher.batch_sizes
        return {"status": "ok", "fps": pipe.fps, "seconds": [min_s, max_s], "max_batch": max_batch,
                "waiting": batcher.waiting, "batches": len(sizes), "largest_batch": max(sizes, default=0)}

    @app.post("/v1/generate")
    async def generate(body: GenerateRequest, format: str = "json"):
        if format not in FORMATS:
            return _error(400, f"format must be one of {', '.join(FORMATS)}, got {format!r}")
        prompt = body.prompt.strip()
        if not prompt or len(prompt) > MAX_PROMPT_CHARS:
            return _error(422, f"prompt must have 1 to {MAX_PROMPT_CHARS} characters, got {len(prompt)}")
        frames = None  # predicted from the text where generation runs (models with a length estimator), else 4 s
        if body.seconds is not None:
            if not min_s <= body.seconds <= max_s:
                return _error(422, f"seconds must be between {min_s:g} and {max_s:g}, got {body.seconds:g}")
            frames = int(round(body.seconds * pipe.fps)) // 4 * 4
        seed = random.randrange(2**31) if body.seed is None else body.seed
        try:
            r = await batcher.submit(Job(prompt, frames, seed, body.guidance, body.steps, body.footskate))
        except QueueFull as e:
            return _error(503, str(e))
        except SMFError as e:
            return _error(422, str(e))
        return _motion_response(r, seed, format)

    @app.post("/v1/timeline")
    async def timeline(body: TimelineRequest, format: str = "json"):
        if format not in FORMATS:
            return _error(400, f"format must be one of {', '.join(FORMATS)}, got {format!r}")
        segments = tuple((seg.prompt.strip(), float(seg.seconds)) for seg in body.segments)
        for i, (prompt, _) in enumerate(segments):
            if not prompt or len(prompt) > MAX_PROMPT_CHARS:
                return _error(422, f"segments.{i}.prompt must have 1 to {MAX_PROMPT_CHARS} characters, "
                                   f"got {len(prompt)}")
        total = sum(sec for _, sec in segments)
        if total > MAX_TIMELINE_SECONDS:
            return _error(422, f"a timeline lasts at most {MAX_TIMELINE_SECONDS:g} s, got {total:g}")
        seed = random.randrange(2**31) if body.seed is None else body.seed
        try:
            r = await batcher.submit(Job("; ".join(p for p, _ in segments), None, seed, body.guidance, body.steps,
                                         body.footskate, segments))
        except QueueFull as e:
            return _error(503, str(e))
        except SMFError as e:
            return _error(422, str(e))
        return _motion_response(r, seed, format)

    @app.post("/v1/convert")
    async def convert(request: Request, filename: str):
        from ..motion.files import load_motion

        suffix = Path(filename).suffix.lower()
        if suffix not in (".bvh", ".npy"):
            return _error(415, f"only .bvh and .npy files can be viewed, got {filename!r}")
        data = await request.body()
        if len(data) > MAX_UPLOAD_BYTES:
            return _error(413, f"request body larger than {MAX_UPLOAD_BYTES} bytes")
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / f"upload{suffix}"
            path.write_bytes(data)
            try:
                m = load_motion(path)  # .npy with allow_pickle=False
            except SMFError as e:
                return _error(422, str(e).replace(str(path), filename))
        if m.skeleton.name != "humanml3d":
            return _error(422, f"{filename}: the viewer shows 22-joint (HumanML3D) motions, not {m.skeleton.name}")
        return JSONResponse({"fps": m.fps, "frames": len(m.joints), "joints": np.round(m.joints, 5).tolist()})

    @app.get("/", include_in_schema=False)
    async def viewer():
        return FileResponse(VIEWER / "index.html")

    app.mount("/viewer", StaticFiles(directory=VIEWER), name="viewer")
    return app


def _bvh_text(result) -> str:
    """The BVH file of a result's rigid body (as `smf generate` writes it)."""
    from ..motion.files import rigid_bvh_text, rigid_pose

    return rigid_bvh_text(result.motion if result.motion is not None else rigid_pose(result.joints), result.fps)
