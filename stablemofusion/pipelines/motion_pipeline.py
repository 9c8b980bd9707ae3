"""MotionPipeline: text -> motion with a trained model, in a few diffusion steps; the public entry, on whatever the
install has.

It holds one :class:`~stablemofusion.backends.base.Backend` (PyTorch where installed, else the exported graphs on
ONNX Runtime: :func:`~stablemofusion.backends.load_backend`) and offers one method per task, each a call of its task
pipeline written once against that backend: ``__call__`` text to motion, ``timeline``, ``edit`` and ``stream``. The
same call gives the same motion on either backend. ``guidance_scale``/``steps``/``sampler`` None mean the model's
defaults (a distilled student: its distilled step count with consistency sampling, guidance as input); every
result carries the :class:`~stablemofusion.core.settings.Settings` it was made with.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..backends import PORTABLE_ADAPTERS, load_backend
from ..backends.base import Backend
from ..core.errors import SMFError
from ..core.folders import default_model_path
from ..core.limits import BATCH_SIZE, DEFAULT_SECONDS, FOOTSKATE_MODES
from ..core.timeline_plan import DEFAULT_OVERLAP
from .edit import EditPipeline
from ..core.final import EngineWarning, LengthClampedWarning, OutOfDomainWarning
from ..core.result import MotionResult
from ..core.settings import Settings
from .stream import STREAM_CHUNK, STREAM_REWIND, MotionStream, StreamPipeline
from .text_to_motion import TextToMotionPipeline
from .timeline import TimelinePipeline


class MotionPipeline:
    """Generate motions from text. Build with :meth:`from_pretrained`; ``backend`` is what runs the network."""

    def __init__(self, backend: Backend):
        self.backend = backend

    @classmethod
    def from_pretrained(cls, path: str | Path | None = None, *, backend: str | None = None, engine: str | None = None,
                        teacher: bool = False, threads: int | None = None, adapter=None,
                        **torch_options) -> "MotionPipeline":
        """The model in ``path`` (a model folder, a training run, or a graphs folder; None: the shipped model; with
        ``teacher`` the teacher it was distilled from). ``backend``: 'torch', 'onnx' or None (torch where
        installed, else onnx); ``engine``: how the torch backend runs ('auto', 'eager', 'fast', 'compiled',
        'graph'; 'onnx' means the onnx backend); ``threads``: the onnx backend's; ``adapter``: ``smf adapt`` files
        merged into the torch weights; ``torch_options``: device, dtype, rigid, text_cache_size."""
        return cls(load_backend(path, backend=backend, engine=engine, teacher=teacher, threads=threads, adapter=adapter,
                                **torch_options))

    def __call__(self, prompts: str | list[str], *, seconds: float | list[float] | None = None,
                 frames: int | list[int] | None = None, guidance_scale: float | None = None, steps: int | None = None,
                 sampler: str | None = None, seed: int | list[int] | None = None, batch_size: int = BATCH_SIZE,
                 progress: bool = False, footskate: str | None = None, footskate_options=None,
                 engine: str | None = None, path=None) -> list[MotionResult]:
        """One motion per prompt (:class:`~stablemofusion.pipelines.text_to_motion.TextToMotionPipeline`).
        ``footskate``: 'off', 'post' (clean up each result) or 'loop' (torch: clean up the predicted x0 in the last
        denoising steps); ``engine``: the torch backend's for this call (default: the pipeline's); ``path``: a root
        path to follow (waypoints in metres, optional times: docs/paths.md)."""
        settings = Settings(guidance_scale=guidance_scale, steps=steps, sampler=sampler, footskate=footskate,
                            footskate_options=footskate_options, engine=engine, batch_size=batch_size)
        return TextToMotionPipeline(self.backend)(prompts, seconds=seconds, frames=frames, seed=seed,
                                                  settings=settings, progress=progress, path=path)

    def timeline(self, segments: list[tuple[str, float]], *, overlap: float = DEFAULT_OVERLAP,
                 guidance_scale: float | None = None, steps: int | None = None, sampler: str | None = None,
                 seed: int | None = None, impose: str = "x0", footskate: str | None = None, footskate_options=None,
                 engine: str | None = None, progress: bool | None = False) -> MotionResult:
        """One continuous motion from (prompt, seconds) segments, of any total length
        (:class:`~stablemofusion.pipelines.timeline.TimelinePipeline`); window j uses ``seed + j``;
        ``progress`` None: a progress bar for long timelines."""
        settings = Settings(guidance_scale=guidance_scale, steps=steps, sampler=sampler, footskate=footskate,
                            footskate_options=footskate_options, engine=engine)
        return TimelinePipeline(self.backend)(segments, overlap=overlap, seed=seed, settings=settings, impose=impose,
                                              progress=progress)

    def edit(self, prompt: str, source: np.ndarray, mode: str, *, keep_start: float = 0.0, keep_end: float = 0.0,
             seconds: float | None = None, path: np.ndarray | None = None, guidance_scale: float | None = None,
             steps: int | None = None, sampler: str | None = None, seed: int | None = None, impose: str = "x0",
             footskate: str | None = None, footskate_options=None, engine: str | None = None,
             progress: bool | None = None) -> MotionResult:
        """Edit ``source`` features (Ts, D) with ``prompt`` (:class:`~stablemofusion.pipelines.edit.EditPipeline`):
        ``mode`` one of :data:`stablemofusion.core.edit_plan.EDIT_MODES`, lengths in seconds."""
        settings = Settings(guidance_scale=guidance_scale, steps=steps, sampler=sampler, footskate=footskate,
                            footskate_options=footskate_options, engine=engine)
        return EditPipeline(self.backend)(prompt, source, mode, keep_start=keep_start, keep_end=keep_end,
                                          seconds=seconds, path=path, seed=seed, settings=settings, impose=impose,
                                          progress=progress)

    def stream(self, prompt: str, *, guidance_scale: float | None = None, steps: int | None = None,
               sampler: str | None = None, seed: int | None = None, chunk: int = STREAM_CHUNK,
               engine: str | None = None, rewind: int = STREAM_REWIND) -> MotionStream:
        """An endless motion following ``prompt`` (:class:`~stablemofusion.pipelines.stream.StreamPipeline`): an
        iterator of :class:`~stablemofusion.pipelines.stream.Chunk` of ``chunk`` frames; ``stream.set_prompt(p)``
        (or ``stream.send(p)``) changes the prompt from the next window on; window j uses ``seed + j``;
        ``stream.cut(n)`` rolls it back to frame ``n`` (any of its last ``rewind`` frames), so that the next
        chunk starts there (continuing from frame ``n - 1``, with the prompt current then)."""
        settings = Settings(guidance_scale=guidance_scale, steps=steps, sampler=sampler, footskate="off", engine=engine)
        return StreamPipeline(self.backend)(prompt, seed=seed, settings=settings, chunk=chunk, rewind=rewind)

    def settings(self, settings: Settings | None = None, *, edit: bool = False, hooks: bool = False) -> Settings:
        """``settings`` (default: the model's defaults) resolved as a call resolves them (``Backend.settings``)."""
        return self.backend.settings(settings, edit=edit, hooks=hooks)

    def predict_seconds(self, prompts: str | list[str]) -> list[float]:
        """The median of the length each prompt's motion may have (seconds); one text is one prompt. A motion whose
        length is not given takes the length model's quantile at its seed's level, so seeds differ in length."""
        return self.backend.predict_seconds(prompts)

    def with_adapters(self, adapters) -> "MotionPipeline":
        """A pipeline of this model with adapters merged into a copy of its weights (the torch backend's
        ``with_adapters``)."""
        if self.backend.name != "torch":
            raise SMFError(PORTABLE_ADAPTERS)
        return MotionPipeline(self.backend.with_adapters(adapters))

    def variant(self, name: str | None) -> "MotionPipeline":
        """The pipeline of the adapted copy named ``name`` (``add_variants``), or this one for None."""
        if name is not None and self.backend.name != "torch":
            raise SMFError(PORTABLE_ADAPTERS)
        return self if name is None else MotionPipeline(self.backend.variant(name))

    def __setattr__(self, name: str, value) -> None:
        """Setting what a backend holds (``pipe.rigid = ...``, ``pipe.text_cache = ...``) sets it on the backend."""
        if name == "backend" or name in type(self).__dict__:
            object.__setattr__(self, name, value)
        else:
            setattr(self.backend, name, value)

    def __getattr__(self, name: str):
        """What only one backend has (the torch backend's model, config, text cache, batch-level ``denoise``; the
        onnx backend's graphs), read through to it."""
        if name == "backend":
            raise AttributeError(name)
        try:
            return getattr(self.backend, name)
        except AttributeError:
            raise AttributeError(f"the {self.backend.name} backend has no {name!r}") from None


__all__ = ["MotionPipeline", "MotionResult", "MotionStream", "Settings", "EngineWarning", "LengthClampedWarning",
           "OutOfDomainWarning", "default_model_path", "DEFAULT_SECONDS", "FOOTSKATE_MODES"]
