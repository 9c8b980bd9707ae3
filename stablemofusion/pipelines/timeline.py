"""Timelines: one continuous motion from (prompt, seconds) segments, window after window
(:mod:`stablemofusion.timeline_plan` plans the windows; each later window is a prefix edit of the motion so far)."""

from __future__ import annotations

import torch
from tqdm import tqdm

from ..edit_plan import edit_hooks, plan_edit
from ..diffusion.schedulers import sampler_spec
from ..errors import SMFError
from ..path_plan import Waypoints, bend_segments, follow, path_segments, placed
from ..timeline_plan import DEFAULT_OVERLAP, plan_windows, segment_frames
from .components import Components
from .result import MotionResult
from .denoise import sample
from ..limits import base_seed
from .settings import Settings

PROGRESS_WINDOWS = 3  # timelines of more windows than this show a progress bar by default


class TimelinePipeline:
    """``pipe(segments, seed=..., settings=...)`` -> one :class:`MotionResult` of the whole timeline."""

    def __init__(self, components: Components):
        self.c = components

    @torch.no_grad()
    def __call__(self, segments: list[tuple[str, float]], *, overlap: float = DEFAULT_OVERLAP, seed: int | None = None,
                 settings: Settings = Settings(), impose: str = "x0", progress: bool | None = None,
                 path: Waypoints | None = None) -> MotionResult:
        """Window j uses ``seed + j``. ``progress``: a tqdm bar over the windows (None: for long timelines); ``path``:
        an explicit root path the whole motion follows (else each segment follows its own path words)."""
        c = self.c
        # 1. check inputs
        segs, paths = path_segments(segment_frames(segments, c.fps))
        # 2. prepare: paths from words (taken out of the prompts), the windows, the settings (later windows continue by editing: hooks) and the seed
        windows = plan_windows(segs, c.max_frames, int(round(overlap * c.fps)), c.min_frames)
        settings = c.settings(settings, hooks=len(windows) > 1)
        if len(windows) > 1:
            check_long(settings.sampler, c.window_seconds)
        base = base_seed(seed)
        # 3. denoise window after window, each continuing the motion so far
        out = torch.zeros(0, int(c.mean.shape[0]), dtype=torch.float64)
        show = len(windows) > PROGRESS_WINDOWS if progress is None else progress
        for j, w in enumerate(tqdm(windows, desc="timeline", unit="window", disable=not show)):
            frames = max(w.frames, c.min_frames)
            if w.keep == 0:
                raw = sample(c, [w.prompt], [frames], settings, [base + j])[0]
            else:
                plan = plan_edit("prefix", out[-w.keep:].numpy(), c.skeleton, keep_start=w.keep, frames=frames)
                x0_hook, xt_hook = edit_hooks(plan, c.mean, c.std, 1, c.device, c.dtype, impose)
                raw = sample(c, [w.prompt], [frames], settings, [base + j], x0_hook=x0_hook,
                             xt_hook=xt_hook)[0]
                raw = plan.project(raw.double()).float()  # exact on the kept part
            out = torch.cat([out, raw[w.keep:w.keep + w.new].double()])
        # 4. post-process: an explicit path followed, else each segment's path bent; the final stage
        placing = None
        if path is not None:
            raw, placing = follow(out.numpy(), None, path, c.fps)
        else:
            raw = bend_segments(out.numpy(), [n for _, n in segs], paths)
        f, motion = c.finish(raw, settings.footskate, settings.footskate_options)
        f, motion = placed(f, motion, placing, c.rigid)
        return MotionResult.build("; ".join(f"{p}:{s:g}" for p, s in segments), f, motion, c.skeleton, c.fps, base)


def check_long(sampler: str, window_seconds: float) -> None:
    """Motions of several windows continue each window by editing: that needs a fast sampler."""
    if not sampler_spec(sampler).fast:
        raise SMFError(f"motions longer than {window_seconds:g} s and timelines are made window by window, which "
                       f"needs a sampler with a precomputed form, not {sampler!r}")
