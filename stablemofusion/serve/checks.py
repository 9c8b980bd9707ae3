"""Every check of a request's input, in one place: strict JSON bodies, text, ranges; a checked request
becomes a :class:`~stablemofusion.serve.worker.Job`. Raises :class:`ServeError` (422 or 400)."""

from __future__ import annotations

import json
import random
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from .errors import ServeError
from .output import MOTION_FORMATS
from .limits import MAX_GUIDANCE, MAX_PROMPT_CHARS, MAX_SEED, MAX_SEGMENTS, MAX_STEPS, MAX_TIMELINE_SECONDS
from .worker import Job

FORMATS = tuple(MOTION_FORMATS)  # json, bvh, npy, glb
STRICT = ConfigDict(extra="forbid", strict=True)  # {"seed": true} and {"seconds": "4"} are errors


class GenerateRequest(BaseModel):
    """The body of POST /v1/generate."""

    model_config = STRICT

    prompt: str
    seconds: float | None = None  # None: predicted from the text (models with a length estimator), else 4 s
    seed: int | None = Field(default=None, ge=0, lt=MAX_SEED)
    guidance: float | None = Field(default=None, ge=0.0, le=MAX_GUIDANCE)  # None: the model's
    steps: int | None = Field(default=None, ge=1, le=MAX_STEPS)  # None: the model's
    footskate: Literal["off", "post", "loop"] = "off"


class Segment(BaseModel):
    """One entry of a timeline: what to do and for how long."""

    model_config = STRICT

    prompt: str
    seconds: float = Field(gt=0.0)


class TimelineRequest(BaseModel):
    """The body of POST /v1/timeline: one continuous motion from several prompts."""

    model_config = STRICT

    segments: list[Segment] = Field(min_length=1, max_length=MAX_SEGMENTS)
    seed: int | None = Field(default=None, ge=0, lt=MAX_SEED)
    guidance: float | None = Field(default=None, ge=0.0, le=MAX_GUIDANCE)  # None: the model's
    steps: int | None = Field(default=None, ge=1, le=MAX_STEPS)  # None: the model's
    footskate: Literal["off", "post", "loop"] = "off"


def parse_body(data: bytes, model: type[BaseModel]) -> BaseModel:
    """A UTF-8 JSON object validated strictly against ``model``."""
    try:
        obj = json.loads(data.decode("utf-8"), parse_constant=_no_constants)
    except UnicodeDecodeError:
        raise ServeError(422, "body: not UTF-8 text") from None
    except (ValueError, RecursionError):
        raise ServeError(422, "body: not valid JSON") from None
    try:
        return model.model_validate(obj)
    except ValidationError as e:
        raise ServeError(422, validation_message(e.errors())) from None


def _no_constants(name: str):
    raise ValueError(f"{name} is not JSON")


def validation_message(errors: list) -> str:
    """The first problem of a validation, as 'field.path: message'."""
    first = errors[0] if errors else {}
    where = ".".join(str(p) for p in first.get("loc", ()) if p not in ("body", "query")) or "body"
    return f"{where}: {first.get('msg', 'invalid request')}"


def check_format(format: str) -> str:
    if format not in FORMATS:
        raise ServeError(400, f"format must be one of {', '.join(FORMATS)}, got {format[:20]!r}")
    return format


def check_prompt(text: str, where: str) -> str:
    """A stripped prompt of 1 to MAX_PROMPT_CHARS characters that is valid Unicode text."""
    prompt = text.strip()
    try:
        prompt.encode("utf-8")
    except UnicodeEncodeError:
        raise ServeError(422, f"{where}: not valid text (it holds a lone surrogate code point)") from None
    if not prompt or len(prompt) > MAX_PROMPT_CHARS:
        raise ServeError(422, f"{where} must have 1 to {MAX_PROMPT_CHARS} characters, got {len(prompt)}")
    return prompt


class RequestChecks:
    """Turns request bodies into jobs for a model of frame rate ``fps`` and length range (frames)."""

    def __init__(self, fps: float, min_frames: int, max_frames: int):
        self.fps, self.min_s, self.max_s = fps, min_frames / fps, max_frames / fps

    def generate(self, body: GenerateRequest) -> Job:
        prompt = check_prompt(body.prompt, "prompt")
        if body.seconds is not None and not self.min_s <= body.seconds <= self.max_s:
            raise ServeError(422, f"seconds must be between {self.min_s:g} and {self.max_s:g}, got {body.seconds:g}")
        return Job(prompt, body.seconds, _seed(body.seed), body.guidance, body.steps, body.footskate)

    def timeline(self, body: TimelineRequest) -> Job:
        segments = tuple((check_prompt(s.prompt, f"segments.{i}.prompt"), s.seconds)
                         for i, s in enumerate(body.segments))
        for i, (_, seconds) in enumerate(segments):
            if seconds * self.fps < 1:
                raise ServeError(422, f"segments.{i}.seconds must be at least one frame ({1 / self.fps:g} s), "
                                      f"got {seconds:g}")
        total = sum(sec for _, sec in segments)
        if total > MAX_TIMELINE_SECONDS:
            raise ServeError(422, f"a timeline lasts at most {MAX_TIMELINE_SECONDS:g} s, got {total:g}")
        return Job("; ".join(p for p, _ in segments), None, _seed(body.seed), body.guidance, body.steps,
                   body.footskate, segments)


def _seed(seed: int | None) -> int:
    return random.randrange(2**31) if seed is None else seed
