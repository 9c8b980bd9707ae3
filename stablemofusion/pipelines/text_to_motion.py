"""Text to motion: one motion per prompt, batched; motions longer than one window are one-segment timelines, and a
prompt that asks for one thing after another ("... then ...") is a timeline of its parts."""

from __future__ import annotations

import warnings

from tqdm import tqdm

from ..backends.base import Backend
from ..core.errors import SMFError
from ..core.final import (NotEnglishWarning, TaughtCaptionWarning, WeakActionWarning, asked_frames, check_batch_request,
                          clamp_message, frames_for)
from ..core.language import language_message, not_english
from ..core.limits import DEFAULT_SECONDS, LENGTH_MULTIPLE, base_seed
from ..core.noise import length_level
from ..core.path_plan import PromptPaths, follow, placed
from ..core.reliability import weak_action, weak_message
from ..core.sequence_plan import ONE_ACTION_SIMILARITY, share_seconds, split_sequence, spread_seconds
from ..core.result import MotionResult
from ..core.settings import Settings
from .timeline import TimelinePipeline


class TextToMotionPipeline:
    """``pipe(prompts, seconds=..., seed=..., settings=...)`` -> one :class:`MotionResult` per prompt."""

    def __init__(self, backend: Backend):
        self.b = backend

    def __call__(self, prompts: str | list[str], *, seconds: float | list[float] | None = None,
                 frames: int | list[int] | None = None, seed: int | list[int] | None = None,
                 settings: Settings = Settings(), progress: bool = False, path=None) -> list[MotionResult]:
        """``seconds``/``frames``: one value or one per prompt; with neither, a length the length model gives for
        the item's seed and stream (its distribution's quantile at :func:`~stablemofusion.core.noise.length_level`;
        else the default length; path words' length spread across seeds the same way); ``path``: a root path to
        follow (:class:`~stablemofusion.core.path_plan.Waypoints` or its JSON form, one for all or one per prompt),
        its length the motion's unless one is given. ``seed``: one for
        all (batch k uses ``seed + k``, a long item i ``seed + i``) or one per prompt (each motion independent of
        those it is batched with); None: a fresh one, reported."""
        b, request = self.b, settings
        # 1. check inputs, the settings resolved for the model
        prompts, secs, frs, per_item = check_batch_request(prompts, seconds, frames, seed)
        settings = b.settings(request)
        n = len(prompts)
        # 2. prepare: each prompt's parts ("... then ..."), paths from words (the model is given the prompt without
        # them), lengths (a path's, else the model's estimate where none is given), seeds, domains
        parts = self.parts(prompts, settings)
        one = [len(p) == 1 for p in parts]
        paths = PromptPaths.read(prompts, path)
        given, (asked, secs) = list(secs), (paths.asked, paths.seconds(prompts, secs, frs))
        unknown = [i for i in range(n) if secs[i] is None and frs[i] is None and one[i]]
        worded = [i for i in range(n) if secs[i] is not None and given[i] is None and frs[i] is None and one[i]
                  and paths.explicit[i] is None] if b.has_length_model else []  # a length from path words
        base = None if per_item else base_seed(seed)
        # the batches of one window each (a length the model predicts is within one, or spreads from path words),
        # and each item's seed and stream there: its noise's, and its length's quantile in the length model's
        # distribution
        predicted = set(unknown) | set(worded)
        over = [one[i] and i not in predicted and frames_for(secs[i], frs[i], b.fps, b.min_frames) > b.max_frames
                for i in range(n)]
        long = [i for i in range(n) if over[i]]
        short = [i for i in range(n) if one[i] and not over[i]]
        batches = [short[a:a + settings.batch_size] for a in range(0, len(short), settings.batch_size)]
        draw = {i: (seed[i], 0) if per_item else (base + k, j) for k, idx in enumerate(batches)
                for j, i in enumerate(idx)}
        drawn = unknown + worded if b.has_length_model else []
        for i, s in zip(drawn, self.drawn_seconds([prompts[i] for i in drawn], [length_level(*draw[i]) for i in drawn],
                                                  [secs[i] for i in drawn])):
            secs[i] = s
        lengths = [frames_for(s, f, b.fps, b.min_frames) if one[i] else 0 for i, (s, f) in enumerate(zip(secs, frs))]
        foreign = {p: why for p in dict.fromkeys(prompts) if (why := not_english(p)) is not None}
        for p, why in foreign.items():
            warnings.warn(language_message(p, why), NotEnglishWarning, stacklevel=3)
        single = [i for i in range(n) if one[i]]
        domains: list = [None] * n
        for i, d in zip(single, b.domains([asked[i] for i in single]) if single else []):
            domains[i] = d
        weak = self.weak([asked[i] for i in single], [domains[i] for i in single])
        # a prompt clearly closest to a move an adapter taught: its model is given that move's nearest clip caption
        # (a motion longer than one window keeps path words it has: its timeline reads them from its prompt)
        routable = {i for i in single if not over[i] or paths.words[i] is None}
        answers = self.answered([prompts[i] for i in sorted(routable)], [domains[i] for i in sorted(routable)])
        said = [answers.get(prompts[i], asked[i]) if i in routable else asked[i] for i in range(n)]
        results: list[MotionResult | None] = [None] * n
        # 3. timelines: prompts of several parts, each part its own segment (a length given, or an explicit path's,
        # shared among them), and motions longer than one window
        for i in (i for i in range(n) if not one[i]):
            total = given[i] if given[i] is not None or paths.explicit[i] is None else \
                paths.explicit[i].seconds(prompts[i])
            segments = self.segments(parts[i], total, frs[i], seed[i] if per_item else base + i)
            own = PromptPaths.read(parts[i])
            checks = b.domains(own.asked)
            plain = [k for k in range(len(parts[i])) if own.words[k] is None]  # a part without path words: answered
            answers = self.answered([parts[i][k] for k in plain], [checks[k] for k in plain])  # with a taught caption
            told = [(answers.get(p, p), s) for p, s in segments]
            r = TimelinePipeline(b)(told, seed=seed[i] if per_item else base + i, settings=request,
                                    path=paths.explicit[i])
            r.prompt, r.sequence = prompts[i], segments
            r.domain = min(checks, key=lambda d: d.similarity) if None not in checks else None
            r.warnings = [d.message(p) for d, p in zip(checks, parts[i]) if d is not None and d.out_of_domain]
            r.warnings += list(self.weak(parts[i], checks).values())
            r.warnings += [d.answer_message(p) for d, p, (t, _) in zip(checks, parts[i], told) if t != p]
            results[i] = r
        for i in long:
            r = TimelinePipeline(b)([(prompts[i] if said[i] == asked[i] else said[i], lengths[i] / b.fps)],
                                    seed=seed[i] if per_item else base + i,
                                    settings=request, path=paths.explicit[i])
            r.prompt, r.domain = prompts[i], domains[i]
            results[i] = r
        # 4. denoise the others in batches
        for k, idx in enumerate(tqdm(batches, desc="generate", unit="batch", disable=not progress)):
            batch_seed = [seed[i] for i in idx] if per_item else base + k
            raw = b.raw_features([said[i] for i in idx], [lengths[i] for i in idx], settings, batch_seed)
            # 5. post-process: each path followed, the final stage of the batch's motions (their rigid fits together)
            bent = [follow(raw[j, :lengths[i]], paths.words[i], paths.explicit[i], b.fps) for j, i in enumerate(idx)]
            finished = b.finish_many([f for f, _ in bent], settings.footskate, settings.footskate_options)
            for (f, motion), (_, placing), i in zip(finished, bent, idx):
                f, motion = placed(f, motion, placing, b.rigid)
                results[i] = MotionResult.build(prompts[i], f, motion, b.skeleton, b.fps,
                                                seed[i] if per_item else batch_seed, domains[i], settings)
        # 6. what each result carries for the user, one line each: its prompt not English, out of domain, an action
        # the model draws badly, the length it asked for clamped to the model's range (a prompt of several parts:
        # its parts', step 3)
        for i, r in enumerate(results):
            if prompts[i] in foreign:
                r.warnings.insert(0, language_message(prompts[i], foreign[prompts[i]]))
            if not one[i]:
                continue
            if domains[i] is not None and domains[i].out_of_domain:
                r.warnings.append(domains[i].message(asked[i]))
            if asked[i] in weak:
                r.warnings.append(weak[asked[i]])
            if said[i] != asked[i]:
                r.warnings.append(domains[i].answer_message(prompts[i]))
            wanted = asked_frames(given[i], frs[i], b.fps)
            if wanted is not None and abs(wanted - r.frames) >= LENGTH_MULTIPLE:  # not a rounding to whole steps
                r.warnings.append(clamp_message(wanted, r.frames, b.fps))
        return results

    def parts(self, prompts: list[str], settings: Settings) -> list[list[str]]:
        """Each prompt's parts: split at its sequence words (:func:`~stablemofusion.core.sequence_plan.
        split_sequence`), unless the whole prompt is nearly one of the model's example sentences (cosine
        similarity ONE_ACTION_SIMILARITY: "a person walks forward then turns left" is one of its actions), or the
        sampler cannot continue a motion part after part (then one motion of the whole prompt, as before)."""
        b = self.b
        parts = [split_sequence(p) for p in prompts]
        several = [i for i, p in enumerate(parts) if len(p) > 1]
        if not several:
            return parts
        try:
            b.check_continues(settings, "a prompt of several parts")
        except SMFError:
            return [[p] for p in prompts]
        with warnings.catch_warnings():  # a decision, not the prompts' own check
            warnings.simplefilter("ignore")
            for i in several:
                wholes = b.domains(PromptPaths.read([prompts[i]]).asked)
                if wholes[0] is None or not wholes[0].closest:
                    continue
                if wholes[0].closest[0][1] >= ONE_ACTION_SIMILARITY:
                    parts[i] = [prompts[i]]
        return parts

    def drawn_seconds(self, texts: list[str], levels: list[float], worded: list[float | None]) -> list[float]:
        """Each text's length (s) at its level of the length model's distribution; where its path words give a length
        (``worded``), that length spread as the model spreads the text's
        (:func:`~stablemofusion.core.sequence_plan.spread_seconds`)."""
        b = self.b
        if not texts:
            return []
        out = b.predict_seconds(texts, levels)
        spread = [k for k, w in enumerate(worded) if w is not None]
        median = b.predict_seconds([texts[k] for k in spread], [0.5] * len(spread)) if spread else []
        for k, mid in zip(spread, median):
            out[k] = spread_seconds(worded[k], out[k], mid, b.fps, b.min_frames, b.max_frames, LENGTH_MULTIPLE)
        return out

    def answered(self, prompts: list[str], domains: list) -> dict[str, str]:
        """Prompt -> the taught caption it is answered with (``DomainCheck.answer``), each warned once
        (:class:`~stablemofusion.core.final.TaughtCaptionWarning`)."""
        out = {}
        for p, d in zip(prompts, domains):
            if d is not None and d.answer is not None and p not in out:
                out[p] = d.answer
                warnings.warn(d.answer_message(p), TaughtCaptionWarning, stacklevel=4)
        return out

    def weak(self, prompts: list[str], domains: list) -> dict[str, str]:
        """Prompt -> a warning, for the in-domain prompts whose closest known action the model draws badly (its
        reliability table) by a margin of WEAK_MARGIN over the closest one it draws well, each warned once."""
        table = self.b.reliability
        out = {}
        for p, d in zip(prompts, domains):
            action = weak_action(d, table)
            if action is not None and p not in out:
                out[p] = weak_message(p, action, table[action])
                warnings.warn(out[p], WeakActionWarning, stacklevel=4)
        return out

    def segments(self, parts: list[str], seconds: float | None, frames: int | None,
                 seed: int) -> list[tuple[str, float]]:
        """The (prompt, seconds) segments of a prompt's parts: each part as long as its path words say (spread as the
        length model spreads the part's lengths: :func:`~stablemofusion.core.sequence_plan.spread_seconds`), else as
        the length model predicts (part k at the level of stream k of the timeline's ``seed``; else the default
        length); a length given for the whole prompt shared among them in those proportions."""
        b = self.b
        own = PromptPaths.read(parts).seconds(parts, [None] * len(parts), [None] * len(parts))
        if b.has_length_model:
            own = self.drawn_seconds(parts, [length_level(seed, k) for k in range(len(parts))], own)
        own = [DEFAULT_SECONDS if s is None else s for s in own]
        total = frames / b.fps if frames is not None else seconds
        shortest = b.min_frames / b.fps
        shared = own if total is None else share_seconds(total, own, shortest)
        if min(shared) < shortest:
            raise SMFError(f"{len(parts)} parts ({'; '.join(parts)}) need at least {shortest:g} s each; "
                           f"{total:g} s is too short for them")
        return list(zip(parts, shared))
