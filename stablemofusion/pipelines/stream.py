"""Live streams: :class:`StreamPipeline` checks a stream's settings and builds a
:class:`~stablemofusion.core.motion_stream.MotionStream` whose windows a backend samples (:class:`BackendWindows`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..backends.base import Backend, Known
from ..core.errors import SMFError
from ..core.limits import base_seed, check_prompt
from ..core.motion_stream import (STREAM_CHUNK, STREAM_KEEP, STREAM_REWIND, Chunk, MotionStream, advance,
                             check_window)
from ..core.settings import Settings


class BackendWindows:
    """The :class:`~stablemofusion.core.motion_stream.WindowSampler` of a backend: windows sampled with their known start
    imposed on every prediction."""

    def __init__(self, backend: Backend):
        self.b = backend
        self.skeleton, self.min_frames, self.dim = backend.skeleton, backend.min_frames, backend.dim

    def __eq__(self, other) -> bool:  # streams of one backend are batched together
        return isinstance(other, BackendWindows) and other.b is self.b

    def __hash__(self) -> int:
        return id(self.b)

    def with_guidance(self, settings: Settings, guidance: float) -> Settings:
        return replace(settings, guidance_scale=guidance).check()

    def sample_window(self, prompts: list[str], frames: int, settings: Settings, seeds: list[int],
                      known: np.ndarray | None) -> np.ndarray:
        raw = self.b.raw_features(prompts, [frames] * len(prompts), settings, list(seeds),
                                  known=None if known is None else Known.prefix(known, frames))
        return raw.astype(np.float64)


class StreamPipeline:
    """``pipe(prompt, seed=..., settings=...)`` -> a :class:`MotionStream` (windows are made as it is read)."""

    def __init__(self, backend: Backend):
        self.b = backend

    def __call__(self, prompt: str, *, seed: int | None = None, settings: Settings = Settings(),
                 chunk: int = STREAM_CHUNK, keep: int = STREAM_KEEP, rewind: int = STREAM_REWIND) -> MotionStream:
        b = self.b
        # 1. check inputs
        check_prompt(prompt, "the prompt")
        settings = b.settings(settings, hooks=True)  # each window after the first continues by editing
        b.check_continues(settings, "a stream (it continues the motion by editing)")
        if settings.footskate != "off":
            raise SMFError("streams have no footskate cleanup (it works on a whole motion); use footskate 'off'")
        check_window(keep, chunk, rewind, b.max_frames)
        # 2. prepare: the seed; the windows are denoised by `advance` as the stream is read
        return MotionStream(BackendWindows(b), prompt, base_seed(seed), settings, chunk, keep, rewind)


__all__ = ["STREAM_CHUNK", "STREAM_KEEP", "STREAM_REWIND", "BackendWindows", "Chunk", "MotionStream",
           "StreamPipeline", "advance"]
