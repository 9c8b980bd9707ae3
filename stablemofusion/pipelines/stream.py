"""Live streams on the torch path: :class:`StreamPipeline` checks a stream's settings and builds a
:class:`~stablemofusion.motion_stream.MotionStream` (written once for both runtimes) whose windows are sampled
by :class:`TorchWindows`."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from ..diffusion.schedulers import sampler_spec
from ..diffusion.sampling import replace_x0
from ..errors import SMFError
from ..limits import base_seed, check_prompt
from ..motion_stream import (STREAM_CHUNK, STREAM_KEEP, STREAM_REWIND, Chunk, MotionStream, advance,
                             check_window)
from .components import Components
from .denoise import sample
from .settings import Settings


class TorchWindows:
    """The :class:`~stablemofusion.motion_stream.WindowSampler` of a torch pipeline's components."""

    def __init__(self, components: Components):
        self.c = components
        self.skeleton, self.min_frames = components.skeleton, components.min_frames
        self.dim = int(components.mean.shape[0])

    def __eq__(self, other) -> bool:  # streams of one pipeline are batched together
        return isinstance(other, TorchWindows) and other.c is self.c

    def __hash__(self) -> int:
        return id(self.c)

    def with_guidance(self, settings: Settings, guidance: float) -> Settings:
        return replace(settings, guidance_scale=guidance).check()

    @torch.no_grad()
    def sample_window(self, prompts: list[str], frames: int, settings: Settings, seeds: list[int],
                      known: np.ndarray | None) -> np.ndarray:
        c, x0_hook = self.c, None
        if known is not None:  # imposed on x0 at every step
            full = torch.zeros(len(prompts), frames, self.dim, dtype=torch.float64)
            full[:, :known.shape[1]] = torch.from_numpy(known)
            mask = torch.zeros(full.shape, dtype=torch.bool)
            mask[:, :known.shape[1]] = True
            x0_hook = replace_x0(c.normalise(full), mask.to(c.device))
        raw = sample(c, prompts, [frames] * len(prompts), settings, seeds, x0_hook=x0_hook)
        return raw.double().numpy()


class StreamPipeline:
    """``pipe(prompt, seed=..., settings=...)`` -> a :class:`MotionStream` (windows are made as it is read)."""

    def __init__(self, components: Components):
        self.c = components

    def __call__(self, prompt: str, *, seed: int | None = None, settings: Settings = Settings(),
                 chunk: int = STREAM_CHUNK, keep: int = STREAM_KEEP, rewind: int = STREAM_REWIND) -> MotionStream:
        c = self.c
        # 1. check inputs
        check_prompt(prompt, "the prompt")
        settings = c.settings(settings, hooks=True)  # each window after the first continues by editing
        if not sampler_spec(settings.sampler).fast:
            raise SMFError(f"streams continue the motion by editing: they need a sampler with a precomputed form, "
                           f"not {settings.sampler!r}")
        if settings.footskate != "off":
            raise SMFError("streams have no footskate cleanup (it works on a whole motion); use footskate 'off'")
        check_window(keep, chunk, rewind, c.max_frames)
        # 2. prepare: the seed; the windows are denoised by `advance` as the stream is read
        return MotionStream(TorchWindows(c), prompt, base_seed(seed), settings, chunk, keep, rewind)


__all__ = ["STREAM_CHUNK", "STREAM_KEEP", "STREAM_REWIND", "Chunk", "MotionStream", "StreamPipeline", "TorchWindows",
           "advance"]
