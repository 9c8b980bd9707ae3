"""MotionPipeline: text -> motion with a trained checkpoint, in a few diffusion steps; the public entry.

It is the shared :class:`~stablemofusion.pipelines.components.Components` with one method per task, each a
thin call of its task pipeline (:mod:`stablemofusion.pipelines`): ``__call__`` text to motion, ``timeline``,
``edit`` and ``stream``; ``sample`` and ``denoise`` are the batch-level calls benchmarks and evaluation use.
The four inference tricks of the paper: text embedded once per prompt (LRU cache across calls); conditional
and unconditional passes in one batched forward; half precision on GPU; an efficient sampler (SDE
DPM-Solver++ 2M with Karras sigmas, 10 steps, by default). A distilled student (``smf distil``) samples by
default with consistency sampling at its distilled step count, one forward per step (guidance as input);
``guidance_scale``/``steps``/``sampler`` None mean the model's defaults (:meth:`Components.settings`: the guidance
scale its config names, else GUIDANCE of :mod:`stablemofusion.pipelines.settings`).
"""

from __future__ import annotations

import numpy as np
import torch

from .diffusion.sampling import DenoiserFn, guided
from .models.base import TextCondition
from .pipelines.components import Components, default_model_path
from .pipelines.edit import EditPipeline
from .pipelines.result import MotionResult
from .pipelines.denoise import sample as sample_raw
from .limits import BATCH_SIZE, DEFAULT_SECONDS, FOOTSKATE_MODES
from .pipelines.settings import EngineWarning, LengthClampedWarning, OutOfDomainWarning, Settings
from .pipelines.stream import STREAM_CHUNK, STREAM_REWIND, MotionStream, StreamPipeline
from .pipelines.text_to_motion import TextToMotionPipeline
from .pipelines.timeline import TimelinePipeline
from .timeline_plan import DEFAULT_OVERLAP


class MotionPipeline(Components):
    """Generate motions from text with a denoiser checkpoint. Build with :meth:`from_pretrained`."""

    def __call__(self, prompts: str | list[str], *, seconds: float | list[float] | None = None,
                 frames: int | list[int] | None = None, guidance_scale: float | None = None, steps: int | None = None,
                 sampler: str | None = None, seed: int | list[int] | None = None, batch_size: int = BATCH_SIZE,
                 progress: bool = False, footskate: str | None = None, footskate_options=None,
                 engine: str | None = None, path=None) -> list[MotionResult]:
        """One motion per prompt (:class:`~stablemofusion.pipelines.text_to_motion.TextToMotionPipeline`).
        ``footskate``: 'off', 'post' (clean up each result) or 'loop' (clean up the predicted x0 in the last
        denoising steps); ``engine``: 'auto', 'eager', 'fast', 'compiled' or 'graph' (default: the pipeline's);
        ``path``: a root path to follow (waypoints in metres, optional times: docs/paths.md)."""
        settings = Settings(guidance_scale=guidance_scale, steps=steps, sampler=sampler, footskate=footskate,
                            footskate_options=footskate_options, engine=engine, batch_size=batch_size)
        return TextToMotionPipeline(self)(prompts, seconds=seconds, frames=frames, seed=seed, settings=settings,
                                          progress=progress, path=path)

    def timeline(self, segments: list[tuple[str, float]], *, overlap: float = DEFAULT_OVERLAP,
                 guidance_scale: float | None = None, steps: int | None = None, sampler: str | None = None,
                 seed: int | None = None, impose: str = "x0", footskate: str | None = None, footskate_options=None,
                 engine: str | None = None, progress: bool | None = False) -> MotionResult:
        """One continuous motion from (prompt, seconds) segments, of any total length
        (:class:`~stablemofusion.pipelines.timeline.TimelinePipeline`); window j uses ``seed + j``;
        ``progress`` None: a progress bar for long timelines."""
        settings = Settings(guidance_scale=guidance_scale, steps=steps, sampler=sampler, footskate=footskate,
                            footskate_options=footskate_options, engine=engine)
        return TimelinePipeline(self)(segments, overlap=overlap, seed=seed, settings=settings, impose=impose,
                                      progress=progress)

    def edit(self, prompt: str, source: np.ndarray, mode: str, *, keep_start: float = 0.0, keep_end: float = 0.0,
             seconds: float | None = None, path: np.ndarray | None = None, guidance_scale: float | None = None,
             steps: int | None = None, sampler: str | None = None, seed: int | None = None, impose: str = "x0",
             footskate: str | None = None, footskate_options=None, engine: str | None = None,
             progress: bool | None = None) -> MotionResult:
        """Edit ``source`` features (Ts, D) with ``prompt`` (:class:`~stablemofusion.pipelines.edit.EditPipeline`):
        ``mode`` one of :data:`stablemofusion.edit_plan.EDIT_MODES`, lengths in seconds."""
        settings = Settings(guidance_scale=guidance_scale, steps=steps, sampler=sampler, footskate=footskate,
                            footskate_options=footskate_options, engine=engine)
        return EditPipeline(self)(prompt, source, mode, keep_start=keep_start, keep_end=keep_end, seconds=seconds,
                                  path=path, seed=seed, settings=settings, impose=impose, progress=progress)

    def stream(self, prompt: str, *, guidance_scale: float | None = None, steps: int | None = None,
               sampler: str | None = None, seed: int | None = None, chunk: int = STREAM_CHUNK,
               engine: str | None = None, rewind: int = STREAM_REWIND) -> MotionStream:
        """An endless motion following ``prompt`` (:class:`~stablemofusion.pipelines.stream.StreamPipeline`): an
        iterator of :class:`~stablemofusion.pipelines.stream.Chunk` of ``chunk`` frames; ``stream.set_prompt(p)``
        (or ``stream.send(p)``) changes the prompt from the next window on; window j uses ``seed + j``;
        ``stream.cut(n)`` rolls it back to frame ``n`` (any of its last ``rewind`` frames), so that the next
        chunk starts there (continuing from frame ``n - 1``, with the prompt current then)."""
        settings = Settings(guidance_scale=guidance_scale, steps=steps, sampler=sampler, footskate="off", engine=engine)
        return StreamPipeline(self)(prompt, seed=seed, settings=settings, chunk=chunk, rewind=rewind)

    @torch.no_grad()
    def sample(self, prompts: list[str], lengths: list[int], *, guidance_scale: float | None = None,
               steps: int | None = None, sampler: str | None = None, seed: int | list[int] | None = None,
               batched_cfg: bool = True,
               footskate: str = "off", footskate_options=None, engine: str | None = None) -> torch.Tensor:
        """Features (B, max(lengths), D) in dataset units (CPU, float32) of the final motions of one batch
        (:meth:`denoise`, then :meth:`finish` on each; frames past an item's length are zero)."""
        raw = self.denoise(prompts, lengths, guidance_scale=guidance_scale, steps=steps, sampler=sampler, seed=seed,
                           batched_cfg=batched_cfg, footskate=footskate, footskate_options=footskate_options,
                           engine=engine)
        out = torch.zeros_like(raw)
        for i, n in enumerate(lengths):
            out[i, :n] = torch.from_numpy(self.finish(raw[i, :n].numpy(), footskate, footskate_options)[0])
        return out

    @torch.no_grad()
    def denoise(self, prompts: list[str], lengths: list[int], *, guidance_scale: float | None = None,
                steps: int | None = None, sampler: str | None = None, seed: int | list[int] | None = None,
                batched_cfg: bool = True,
                footskate: str = "off", footskate_options=None, engine: str | None = None) -> torch.Tensor:
        """The model's raw features (B, max(lengths), D) of one batch in dataset units (CPU, float32), before
        the final stage (:func:`stablemofusion.pipelines.denoise.sample`)."""
        settings = self.settings(Settings(guidance_scale=guidance_scale, steps=steps, sampler=sampler,
                                          footskate=footskate, footskate_options=footskate_options, engine=engine))
        return sample_raw(self, prompts, lengths, settings, seed, batched_cfg=batched_cfg)

    def engine_for(self, sampler: str | None, engine: str | None = None) -> str:
        """The engine a call runs with: ``engine`` (default: this pipeline's) resolved for the sampler (None:
        the model's)."""
        return self.settings(Settings(sampler=sampler, engine=engine)).engine

    def guided(self, cond: TextCondition, uncond: TextCondition | None, mask: torch.Tensor, scale: float,
               batched: bool = True) -> DenoiserFn:
        """The model under the text condition, with classifier-free guidance unless ``scale`` is 1 (or the
        model is a student, whose ``cond`` already holds the scale and ``uncond`` is None)."""
        return guided(self.model, cond, None if scale == 1.0 else uncond, mask, scale, batched)


__all__ = ["MotionPipeline", "MotionResult", "MotionStream", "Settings", "EngineWarning", "LengthClampedWarning",
           "OutOfDomainWarning",
           "default_model_path", "DEFAULT_SECONDS", "FOOTSKATE_MODES"]
