"""Text to motion: one motion per prompt, batched; motions longer than one window are one-segment timelines."""

from __future__ import annotations

import torch
from tqdm import tqdm

from ..limits import base_seed
from ..path_plan import PromptPaths, follow, placed
from .components import Components
from .denoise import sample
from .final import check_batch_request
from .result import MotionResult
from .settings import Settings
from .timeline import TimelinePipeline


class TextToMotionPipeline:
    """``pipe(prompts, seconds=..., seed=..., settings=...)`` -> one :class:`MotionResult` per prompt."""

    def __init__(self, components: Components):
        self.c = components

    @torch.no_grad()
    def __call__(self, prompts: str | list[str], *, seconds: float | list[float] | None = None,
                 frames: int | list[int] | None = None, seed: int | list[int] | None = None,
                 settings: Settings = Settings(), progress: bool = False, path=None) -> list[MotionResult]:
        """``seconds``/``frames``: one value or one per prompt; with neither, the model's length estimate (or
        the default length); ``path``: a root path to follow (:class:`~stablemofusion.path_plan.Waypoints` or its
        JSON form, one for all or one per prompt), its length the motion's unless one is given. ``seed``: one for all (batch k uses ``seed + k``, a long item i ``seed + i``) or
        one per prompt (each motion independent of those it is batched with); None: a fresh one, reported."""
        c = self.c
        # 1. check inputs
        prompts, secs, frs, per_item = check_batch_request(prompts, seconds, frames, seed)
        settings = c.settings(settings)
        n = len(prompts)
        # 2. prepare: paths from words (the model is given the prompt without them), lengths (a path's, else the
        # model's estimate where none is given), seeds, domains
        paths = PromptPaths.read(prompts, path)
        asked, secs = paths.asked, paths.seconds(prompts, secs, frs)
        unknown = [i for i in range(n) if secs[i] is None and frs[i] is None]
        if unknown and c.length_estimator is not None:
            for i, s in zip(unknown, c.predict_seconds([prompts[i] for i in unknown])):
                secs[i] = s
        lengths = [c.frames_for(s, f) for s, f in zip(secs, frs)]
        base = None if per_item else base_seed(seed)
        domains = c.domains(asked)
        results: list[MotionResult | None] = [None] * n
        # 3. motions longer than one window: one-segment timelines
        for i in (i for i in range(n) if lengths[i] > c.max_frames):
            r = TimelinePipeline(c)([(prompts[i], lengths[i] / c.fps)], seed=seed[i] if per_item else base + i,
                                    settings=settings, path=paths.explicit[i])
            r.prompt, r.domain = prompts[i], domains[i]
            results[i] = r
        # 4. denoise the others in batches
        short = [i for i in range(n) if lengths[i] <= c.max_frames]
        starts = range(0, len(short), settings.batch_size)
        for k, start in enumerate(tqdm(starts, desc="generate", unit="batch", disable=not progress)):
            idx = short[start:start + settings.batch_size]
            batch_seed = [seed[i] for i in idx] if per_item else base + k
            raw = sample(c, [asked[i] for i in idx], [lengths[i] for i in idx], settings, batch_seed)
            # 5. post-process: each path followed, the final stage of the batch's motions (their rigid fits together)
            bent = [follow(raw[j, :lengths[i]].numpy(), paths.words[i], paths.explicit[i], c.fps)
                    for j, i in enumerate(idx)]
            finished = c.finish_many([f for f, _ in bent], settings.footskate, settings.footskate_options)
            for (f, motion), (_, placing), i in zip(finished, bent, idx):
                f, motion = placed(f, motion, placing, c.rigid)
                results[i] = MotionResult.build(prompts[i], f, motion, c.skeleton, c.fps,
                                                seed[i] if per_item else batch_seed, domains[i])
        return results
