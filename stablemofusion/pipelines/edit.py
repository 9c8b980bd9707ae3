"""Editing: keep part of a source motion (its start, end, both, half of the body, or its root path) and generate
the rest from text (:mod:`stablemofusion.core.edit_plan` plans the edit; the backend imposes it at every step)."""

from __future__ import annotations

import numpy as np

from ..backends.base import Backend, Known
from ..core.edit_plan import check_edit_inputs, plan_edit_for, splice_rigid
from ..core.limits import base_seed, check_prompt
from ..motion.rigid import rigid_to_features
from ..motion.root import headings, place_like, place_rigid_like, root_xz
from ..core.result import MotionResult
from ..core.settings import Settings

PROGRESS_SECONDS = 5.0  # edits longer than this show a progress bar by default


class EditPipeline:
    """``pipe(prompt, source, mode, ...)`` -> the edited :class:`MotionResult`, in the source's canonical
    frame."""

    def __init__(self, backend: Backend):
        self.b = backend

    def __call__(self, prompt: str, source: np.ndarray, mode: str, *, keep_start: float = 0.0, keep_end: float = 0.0,
                 seconds: float | None = None, path: np.ndarray | None = None, seed: int | None = None,
                 settings: Settings = Settings(), impose: str = "x0", progress: bool | None = None) -> MotionResult:
        """``source`` features (Ts, D) in dataset units (:func:`stablemofusion.core.edit_plan.source_features` converts
        joints and BVH); ``keep_start`` / ``keep_end`` seconds; ``seconds`` the output length (default the
        source's: the output then has the source's frame count); ``path`` (T, 2) metres for 'trajectory';
        ``impose`` 'x0' or 'xt' (torch backend). ``progress``: a progress bar over the denoising steps (None: for
        edits longer than PROGRESS_SECONDS; where the backend's loop runs step by step)."""
        b = self.b
        # 1. check inputs; the settings of an edit (a student: more steps than its own)
        check_prompt(prompt, "the prompt")
        check_edit_inputs(mode, keep_start, keep_end, seconds)
        settings = b.settings(settings, edit=True, hooks=True)
        b.check_continues(settings, "editing")
        # 2. prepare: the plan and the seed
        seed = base_seed(seed)
        plan = plan_edit_for(mode, source, b.skeleton, b.fps, b.min_frames, b.max_frames, keep_start=keep_start,
                             keep_end=keep_end, seconds=seconds, path=path)
        known = Known.of_plan(plan, impose)
        # 3. denoise with the known part imposed, exact on it after the last step
        show = plan.frames / b.fps > PROGRESS_SECONDS if progress is None else progress
        raw = b.raw_features([prompt], [plan.frames], settings, [seed], known=known, progress=show)[0]
        (f, motion), = b.finish_many([plan.project(raw.astype(np.float64)).astype(np.float32)], settings.footskate,
                                     settings.footskate_options)
        # 4. post-process: place the output like the source, splice the source's kept rigid body back in
        src = np.asarray(source, dtype=np.float64)
        anchor = None
        if plan.anchor is not None:  # the output is placed so that its kept end is where the source has it
            a, s = plan.anchor
            anchor = (a, headings(f)[a], root_xz(f)[a], headings(src)[s], root_xz(src)[s])
        if motion is None:
            r = MotionResult.build(prompt, f, None, b.skeleton, b.fps, seed, settings=settings)
            if anchor is not None:
                r.joints = place_like(r.joints, *anchor)
            return r
        motion = motion if anchor is None else place_rigid_like(motion, *anchor)
        (_, source_body), = b.finish_many([src])
        motion = splice_rigid(motion, source_body, plan)
        return MotionResult.build(prompt, rigid_to_features(motion, f, b.rigid)[1], motion, b.skeleton, b.fps, seed,
                                  settings=settings)
