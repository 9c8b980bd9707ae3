"""Editing: keep part of a source motion (its start, end, both, half of the body, or its root path) and generate
the rest from text (:mod:`stablemofusion.edit_plan` plans the edit and builds its sampling hooks)."""

from __future__ import annotations

import numpy as np
import torch

from ..edit_plan import check_edit_inputs, edit_hooks, plan_edit_for, splice_rigid
from ..diffusion.schedulers import sampler_spec
from ..errors import SMFError
from ..motion.rigid import rigid_to_features
from ..motion.root import headings, place_like, place_rigid_like, root_xz
from .components import Components
from .result import MotionResult
from .denoise import sample
from ..limits import base_seed, check_prompt
from .settings import Settings

PROGRESS_SECONDS = 5.0  # edits longer than this show a progress bar by default


class EditPipeline:
    """``pipe(prompt, source, mode, ...)`` -> the edited :class:`MotionResult`, in the source's canonical
    frame."""

    def __init__(self, components: Components):
        self.c = components

    @torch.no_grad()
    def __call__(self, prompt: str, source: np.ndarray, mode: str, *, keep_start: float = 0.0, keep_end: float = 0.0,
                 seconds: float | None = None, path: np.ndarray | None = None, seed: int | None = None,
                 settings: Settings = Settings(), impose: str = "x0", progress: bool | None = None) -> MotionResult:
        """``source`` features (Ts, D) in dataset units (:func:`stablemofusion.edit_plan.source_features` converts
        joints and BVH); ``keep_start`` / ``keep_end`` seconds; ``seconds`` the output length (default the
        source's: the output then has the source's frame count); ``path`` (T, 2) metres for 'trajectory'.
        ``progress``: a tqdm bar over the denoising steps (None: for edits longer than PROGRESS_SECONDS)."""
        c = self.c
        # 1. check inputs
        check_prompt(prompt, "the prompt")
        check_edit_inputs(mode, keep_start, keep_end, seconds)
        settings = c.settings(settings, edit=True, hooks=True)  # a student: more steps than its own
        if not sampler_spec(settings.sampler).fast:
            raise SMFError(f"editing needs a sampler with a precomputed form, not {settings.sampler!r}")
        # 2. prepare: the plan, its hooks and the seed
        seed = base_seed(seed)
        plan = plan_edit_for(mode, source, c.skeleton, c.fps, c.min_frames, c.max_frames, keep_start=keep_start,
                             keep_end=keep_end, seconds=seconds, path=path)
        x0_hook, xt_hook = edit_hooks(plan, c.mean, c.std, 1, c.device, c.dtype, impose)
        # 3. denoise (the table loop: hooks run eagerly), exact on the known part after the last step
        show = plan.frames / c.fps > PROGRESS_SECONDS if progress is None else progress
        raw = sample(c, [prompt], [plan.frames], settings, [seed], x0_hook=x0_hook,
                     xt_hook=xt_hook, progress=show)
        f, motion = c.finish(plan.project(raw[0].double()).float().numpy(), settings.footskate,
                             settings.footskate_options)
        # 4. post-process: place the output like the source, splice the source's kept rigid body back in
        src = np.asarray(source, dtype=np.float64)
        anchor = None
        if plan.anchor is not None:  # the output is placed so that its kept end is where the source has it
            a, b = plan.anchor
            anchor = (a, headings(f)[a], root_xz(f)[a], headings(src)[b], root_xz(src)[b])
        if motion is None:
            r = MotionResult.build(prompt, f, None, c.skeleton, c.fps, seed)
            if anchor is not None:
                r.joints = place_like(r.joints, *anchor)
            return r
        motion = motion if anchor is None else place_rigid_like(motion, *anchor)
        motion = splice_rigid(motion, c.finish(src)[1], plan)
        return MotionResult.build(prompt, rigid_to_features(motion, f, c.rigid)[1], motion, c.skeleton, c.fps, seed)


