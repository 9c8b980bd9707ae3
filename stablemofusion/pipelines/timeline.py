"""Timelines: one continuous motion from (prompt, seconds) segments, window after window
(:mod:`stablemofusion.core.timeline_plan` plans the windows; each later window is a prefix edit of the motion so far)."""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from ..backends.base import Backend, Known
from ..core.edit_plan import continue_features, plan_edit
from ..core.limits import base_seed
from ..core.path_plan import Waypoints, bend_segments, follow, path_segments, placed
from ..core.timeline_plan import DEFAULT_OVERLAP, plan_windows, segment_frames
from ..core.result import MotionResult
from ..core.settings import Settings

PROGRESS_WINDOWS = 3  # timelines of more windows than this show a progress bar by default


class TimelinePipeline:
    """``pipe(segments, seed=..., settings=...)`` -> one :class:`MotionResult` of the whole timeline."""

    def __init__(self, backend: Backend):
        self.b = backend

    def __call__(self, segments: list[tuple[str, float]], *, overlap: float = DEFAULT_OVERLAP, seed: int | None = None,
                 settings: Settings = Settings(), impose: str = "x0", progress: bool | None = None,
                 path: Waypoints | None = None) -> MotionResult:
        """Window j uses ``seed + j``. ``progress``: a progress bar over the windows (None: for long timelines);
        ``path``: an explicit root path the whole motion follows (else each segment follows its own path words)."""
        b = self.b
        # 1. check inputs
        segs, paths = path_segments(segment_frames(segments, b.fps))
        # 2. prepare: paths from words (taken out of the prompts), the windows, the settings (later windows continue
        # by editing: hooks) and the seed
        windows = plan_windows(segs, b.max_frames, int(round(overlap * b.fps)), b.min_frames)
        settings = b.settings(settings, hooks=len(windows) > 1)
        if len(windows) > 1:
            b.check_continues(settings, f"a motion longer than {b.max_frames / b.fps:g} s (made window by window)")
        base = base_seed(seed)
        # 3. denoise window after window, each continuing the motion so far
        out = np.zeros((0, b.dim))
        show = len(windows) > PROGRESS_WINDOWS if progress is None else progress
        for j, w in enumerate(tqdm(windows, desc="timeline", unit="window", disable=not show)):
            frames = max(w.frames, b.min_frames)
            if w.keep == 0:
                raw = b.raw_features([w.prompt], [frames], settings, [base + j])[0]
            else:
                plan = plan_edit("prefix", out[-w.keep:], b.skeleton, keep_start=w.keep, frames=frames)
                raw = b.raw_features([w.prompt], [frames], settings, [base + j], known=Known.of_plan(plan, impose))[0]
                # exact on the kept part, the seam blended (the graph continue.onnx is this function)
                raw = continue_features(raw.astype(np.float64), plan.known, w.keep).astype(np.float32)
            out = np.concatenate([out, raw[w.keep:w.keep + w.new].astype(np.float64)])
        # 4. post-process: an explicit path followed, else each segment's path bent; the final stage
        placing = None
        if path is not None:
            out, placing = follow(out, None, path, b.fps)
        else:
            out = bend_segments(out, [n for _, n in segs], paths)
        (f, motion), = b.finish_many([out], settings.footskate, settings.footskate_options)
        f, motion = placed(f, motion, placing, b.rigid)
        return MotionResult.build("; ".join(f"{p}:{s:g}" for p, s in segments), f, motion, b.skeleton, b.fps, base,
                                  settings=settings)
