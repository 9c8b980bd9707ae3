"""Every check of a request's input, in one place: strict JSON bodies, text, ranges; a checked request
becomes a :class:`~stablemofusion.serve.worker.Job`. Raises :class:`ServeError` (422 or 400)."""

from __future__ import annotations

import json
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..core import limits
from ..core.sequence_plan import split_sequence
from ..core.errors import SMFError
from ..robots.model import mujoco
from .http_errors import ServeError
from .responses import MOTION_FORMATS
from .server_limits import MAX_REQUEST_COST
from .worker import Job

FORMATS = tuple(MOTION_FORMATS)  # json, bvh, npy, glb
STRICT = ConfigDict(extra="forbid", strict=True)  # {"seed": true} and {"seconds": "4"} are errors


class PathBody(BaseModel):
    """A root path with times: {"points": [[x, z], ...], "times": [seconds, ...]} (stablemofusion/core/path_plan.py)."""

    model_config = STRICT

    points: list[list[float]]
    times: list[float] | None = None


class GenerateRequest(BaseModel):
    """The body of POST /v1/generate."""

    model_config = STRICT

    prompt: str
    seconds: float | None = None  # None: predicted from the text (models with a length estimator), else 4 s
    seed: int | None = None  # None: a fresh one, reported; ranges: stablemofusion/core/limits.py, checked in RequestChecks
    guidance: float | None = None  # None: the model's
    steps: int | None = None  # None: the model's
    footskate: Literal["off", "post", "loop"] = limits.FOOTSKATE
    adapter: str | None = None  # None: the base model; else the name of an adapter the server loaded
    path: PathBody | list[list[float]] | None = None  # a root path to follow: [[x, z], ...] metres, or with times
    robot: Literal["g1", "h1"] | None = None  # also retarget to this shipped robot: the answer is its trajectory


class Segment(BaseModel):
    """One entry of a timeline: what to do and for how long."""

    model_config = STRICT

    prompt: str
    seconds: float


class TimelineRequest(BaseModel):
    """The body of POST /v1/timeline: one continuous motion from several prompts."""

    model_config = STRICT

    segments: list[Segment] = Field(min_length=1, max_length=limits.MAX_SEGMENTS)
    seed: int | None = None
    guidance: float | None = None
    steps: int | None = None
    footskate: Literal["off", "post", "loop"] = limits.FOOTSKATE
    adapter: str | None = None


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
    """A stripped prompt within the limits that is valid Unicode text."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise ServeError(422, f"{where}: not valid text (it holds a lone surrogate code point)") from None
    return checked(limits.check_prompt, text, where)


def checked(check, *args):
    """``check(*args)`` of :mod:`stablemofusion.core.limits`, its SMFError as a 422."""
    try:
        return check(*args)
    except SMFError as e:
        raise ServeError(422, str(e)) from None


class RequestChecks:
    """Turns request bodies into jobs for a model of frame rate ``fps``, with the limits of every door
    (:mod:`stablemofusion.core.limits`)."""

    def __init__(self, model, max_cost: float = MAX_REQUEST_COST, adapters: tuple[str, ...] = ()):
        """``model``: the served model's :class:`~stablemofusion.serve.worker.ServedModel` (frame rate, window,
        default steps and guidance); ``max_cost`` the most work one request may ask for; ``adapters`` the names of
        the adapters loaded beside the model."""
        self.fps, self.max_cost, self.adapters = model.fps, max_cost, tuple(adapters)
        self.window_s = model.max_frames / model.fps
        self.default_steps, self.default_guidance = model.steps, model.guidance
        self.student = model.student

    def _check_cost(self, seconds: float | None, body) -> float:
        """A request's work (limits.request_cost); 422 where it is more than MAX_REQUEST_COST."""
        steps = body.steps or self.default_steps
        guidance = self.default_guidance if body.guidance is None else body.guidance
        cost = limits.request_cost(seconds or self.window_s, steps, not self.student and guidance != 1.0,
                                   body.footskate)
        if cost > self.max_cost:
            raise ServeError(422, f"this request asks for {cost:.0f} units of work, the server takes at most "
                                  f"{self.max_cost:.0f} (seconds x steps, more with guidance and footskate "
                                  "cleanup): ask for fewer seconds or steps, or footskate 'post'")
        return cost

    def _adapter(self, body) -> str | None:
        if body.adapter is not None and body.adapter not in self.adapters:
            raise ServeError(422, f"adapter: no adapter named {body.adapter[:60]!r} is loaded (loaded: "
                                  f"{', '.join(self.adapters) or 'none'})")
        return body.adapter

    def _common(self, body) -> tuple[int, float | None, int | None]:
        checked(limits.check_guidance, body.guidance)
        checked(limits.check_steps, body.steps)
        return checked(limits.base_seed, body.seed), body.guidance, body.steps

    def generate(self, body: GenerateRequest) -> Job:
        prompt = check_prompt(body.prompt, "prompt")
        if body.robot is not None and mujoco is None:
            raise ServeError(422, "robot: this server cannot retarget to robots (MuJoCo is not installed: pip install "
                                  "'stablemofusion[robot]')")
        checked(limits.check_seconds, body.seconds)
        seed, guidance, steps = self._common(body)
        path = None
        if body.path is not None:
            from ..core.path_plan import Waypoints

            data = body.path.model_dump() if isinstance(body.path, PathBody) else body.path
            path = checked(Waypoints.read, data)
            checked(limits.check_seconds, body.seconds or path.seconds(prompt), "the path's seconds")
        # a prompt of several parts is made part after part, each up to a window long where no length is given
        parts = len(split_sequence(prompt))
        own = body.seconds or (path.seconds(prompt) if path is not None else None)
        cost = self._check_cost(own or (parts * self.window_s if parts > 1 else None), body)
        return Job(prompt, body.seconds, seed, guidance, steps, body.footskate, adapter=self._adapter(body), path=path,
                   cost=cost)

    def timeline(self, body: TimelineRequest) -> Job:
        segments = tuple((check_prompt(s.prompt, f"segments.{i}.prompt"), s.seconds)
                         for i, s in enumerate(body.segments))
        for i, (_, seconds) in enumerate(segments):
            if not seconds * self.fps >= 1:
                raise ServeError(422, f"segments.{i}.seconds must be at least one frame ({1 / self.fps:g} s), "
                                      f"got {seconds:g}")
        checked(limits.check_seconds, sum(sec for _, sec in segments), "a timeline's total seconds")
        seed, guidance, steps = self._common(body)
        cost = self._check_cost(sum(sec for _, sec in segments), body)
        return Job("; ".join(p for p, _ in segments), None, seed, guidance, steps, body.footskate, segments,
                   adapter=self._adapter(body), cost=cost)
