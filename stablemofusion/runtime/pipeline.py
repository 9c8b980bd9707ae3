"""Text to motion on the portable runtime (ONNX Runtime and numpy, no torch): the same steps, checks, seeds and
final stage as the torch path's :class:`~stablemofusion.pipelines.text_to_motion.TextToMotionPipeline`, so the
same prompt, seed and length give the same motion (docs/runtime.md)."""

from __future__ import annotations

import warnings
from collections import OrderedDict
from functools import cached_property
from importlib import resources
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ..errors import SMFError
from ..limits import (BATCH_SIZE, FOOTSKATE, PORTABLE_ENGINE, PORTABLE_FOOTSKATE, STUDENT_EDIT_STEPS, base_seed,
                      check_batch_size, check_footskate, check_guidance, check_prompt, check_steps)
from ..motion.rigid import DEFAULT_FIT, rigid_to_features
from ..motion.root import headings, place_rigid_like, root_xz
from ..motion.skeleton import get_skeleton
from ..pipelines.final import OutOfDomainWarning, check_batch_request, finish_many, frames_for
from ..pipelines.result import MotionResult
from ..edit_plan import check_edit_inputs, plan_edit, plan_edit_for, splice_rigid, x0_constraint
from ..path_plan import PromptPaths, bend_segments, follow, path_segments, placed
from ..motion_stream import STREAM_CHUNK, STREAM_KEEP, STREAM_REWIND, MotionStream, check_window
from ..timeline_plan import DEFAULT_OVERLAP, plan_windows, segment_frames
from ..text.names import GRAPHS_DIR
from .graphs import TEACHER_INSTALL, PortableGraphs
from .sampling import sample



def default_graphs_path() -> Path | None:
    """The portable graphs of the model shipped inside the package, if any."""
    path = Path(str(resources.files("stablemofusion") / "assets" / "default_model" / GRAPHS_DIR))
    return path if (path / "graphs.json").is_file() else None


class PortablePipeline:
    """``pipe(prompts, seconds=..., seed=...)`` -> one :class:`MotionResult` per prompt, on the portable graphs
    of a model (``teacher``: its teacher's). Build with :meth:`from_pretrained`."""

    def __init__(self, graphs: PortableGraphs, *, teacher: bool = False, text_cache_size: int = 1024):
        model = graphs.teacher if teacher else graphs.model
        if model is None:
            raise SMFError(f"the teacher is not installed: {TEACHER_INSTALL}" if graphs.teacher_missing
                           else "these graphs hold no teacher")
        self.graphs, self.model = graphs, model
        self.skeleton = get_skeleton(model.entry["skeleton"])
        self.fps, self.min_frames, self.max_frames, self.dim = model.fps, model.min_frames, model.max_frames, model.dim
        self.rigid = DEFAULT_FIT
        self._cache: OrderedDict[str, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._cache_size = text_cache_size

    @classmethod
    def from_pretrained(cls, path: str | Path | None = None, *, teacher: bool = False,
                        threads: int | None = None) -> "PortablePipeline":
        """The graphs folder ``path`` (or a model folder holding one in ``onnx/``); None: the shipped model's."""
        if path is None:
            path = default_graphs_path()
            if path is None:
                raise SMFError("this install ships no portable graphs of the default model")
        path = Path(path)
        if not (path / "graphs.json").is_file() and (path / GRAPHS_DIR / "graphs.json").is_file():
            path = path / GRAPHS_DIR
        return cls(PortableGraphs(path, threads), teacher=teacher)

    # ---------------------------------------------------------------- text
    @cached_property
    def known_actions(self):
        """The model's known actions and out-of-domain detector (None without)."""
        return self.graphs.known_actions(_TextCache(self))

    def encode(self, prompts: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frozen tokens (B, L, C), mask (B, L), sentence embeddings (B, C), each prompt encoded once (LRU)."""
        todo = [p for p in dict.fromkeys(prompts) if p not in self._cache]
        if todo:
            tokens, mask, sentence = self.graphs.encode(todo)
            for p, t, m, s in zip(todo, tokens, mask, sentence):
                self._cache[p] = (t[:int(m.sum())], s)
        rows = []
        for p in prompts:
            self._cache.move_to_end(p)
            rows.append(self._cache[p])
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        L = max(len(r[0]) for r in rows)
        tokens = np.zeros((len(rows), L, rows[0][0].shape[-1]), np.float32)
        mask = np.zeros((len(rows), L), bool)
        for i, (t, _) in enumerate(rows):
            tokens[i, :len(t)], mask[i, :len(t)] = t, True
        return tokens, mask, np.stack([s for _, s in rows])

    def predict_seconds(self, prompts: str | list[str]) -> list[float]:
        """The length each prompt's motion is expected to have (seconds), from the length model; one text is one
        prompt (not one per character)."""
        prompts = [prompts] if isinstance(prompts, str) else list(prompts)
        tokens, mask, _ = self.encode(prompts)
        frames = self.graphs.predict_frames(tokens, mask)
        if frames is None:
            raise SMFError("this model has no length model; give the length")
        return [int(f) / self.fps for f in np.clip(frames, self.min_frames, self.max_frames)]

    def domains(self, prompts: list[str]) -> list:
        """Each prompt's closest known action (None without known actions), warning once per out-of-domain
        prompt."""
        known = self.known_actions
        if known is None:
            return [None] * len(prompts)
        checks = list(known.check_many(prompts))
        for p, d in dict(zip(prompts, checks)).items():
            if d.out_of_domain:
                warnings.warn(d.message(p), OutOfDomainWarning, stacklevel=3)
        return checks

    # ---------------------------------------------------------------- generate
    def __call__(self, prompts: str | list[str], *, seconds: float | list[float] | None = None,
                 frames: int | list[int] | None = None, seed: int | list[int] | None = None,
                 guidance_scale: float | None = None, steps: int | None = None, sampler: str | None = None,
                 footskate: str | None = None, footskate_options=None, batch_size: int = BATCH_SIZE,
                 engine: str | None = None, progress: bool = False, path=None) -> list[MotionResult]:
        """One motion per prompt (the torch path's rules: seeds, lengths, batches, final stage); ``engine``: None or
        'onnx' (the keyword the torch pipeline takes), ``progress`` unused (a call takes milliseconds); ``path``: a
        root path to follow (:class:`~stablemofusion.path_plan.Waypoints` or its JSON form; one for all prompts or
        one per prompt), its length the motion's unless one is given."""
        m = self.model
        # 1. check inputs, defaults from the model
        prompts, secs, frs, per_item = check_batch_request(prompts, seconds, frames, seed)
        sampling, footskate = self._settings(guidance_scale, steps, sampler, footskate, engine)
        check_batch_size(batch_size)
        n = len(prompts)
        # 2. prepare: paths from words (the model is given the prompt without them), lengths (a path's, else the
        # model's estimate where none is given), seeds, domains
        paths = PromptPaths.read(prompts, path)
        asked, secs = paths.asked, paths.seconds(prompts, secs, frs)
        unknown = [i for i in range(n) if secs[i] is None and frs[i] is None]
        if unknown and self.graphs.has_length_model:
            for i, s in zip(unknown, self.predict_seconds([prompts[i] for i in unknown])):
                secs[i] = s
        lengths = [frames_for(s, f, self.fps, self.min_frames) for s, f in zip(secs, frs)]
        base = None if per_item else base_seed(seed)
        domains = self.domains(asked)
        results: list[MotionResult | None] = [None] * n
        # 3. motions longer than one window: one-segment timelines
        for i in (i for i in range(n) if lengths[i] > self.max_frames):
            r = self._timeline([(prompts[i], lengths[i] / self.fps)], DEFAULT_OVERLAP,
                               seed[i] if per_item else base + i, sampling, footskate, footskate_options,
                               paths.explicit[i])
            r.prompt, r.domain = prompts[i], domains[i]
            results[i] = r
        # 4. denoise the others in batches (batch k uses seed + k, as the torch path)
        short = [i for i in range(n) if lengths[i] <= self.max_frames]
        for k, start in enumerate(range(0, len(short), batch_size)):
            idx = short[start:start + batch_size]
            batch_seed = [seed[i] for i in idx] if per_item else base + k
            tokens, mask, _ = self.encode([asked[i] for i in idx])
            raw = sample(m, tokens, mask, [lengths[i] for i in idx], batch_seed, **sampling)
            # 5. post-process: each path followed, the final stage of the batch's motions (their rigid fits together)
            bent = [follow(raw[j, :lengths[i]], paths.words[i], paths.explicit[i], self.fps)
                    for j, i in enumerate(idx)]
            finished = finish_many([f for f, _ in bent], self.skeleton, self.fps, self.rigid, footskate,
                                   footskate_options)
            for (f, motion), (_, placing), i in zip(finished, bent, idx):
                f, motion = placed(f, motion, placing, self.rigid)
                results[i] = MotionResult.build(prompts[i], f, motion, self.skeleton, self.fps,
                                                seed[i] if per_item else batch_seed, domains[i])
        return results

    def timeline(self, segments: list[tuple[str, float]], *, overlap: float = DEFAULT_OVERLAP, seed: int | None = None,
                 guidance_scale: float | None = None, steps: int | None = None, sampler: str | None = None,
                 footskate: str | None = None, footskate_options=None, engine: str | None = None,
                 progress: bool | None = None) -> MotionResult:
        """One continuous motion from (prompt, seconds) segments, window after window (window j uses ``seed + j``),
        as the torch path's :class:`~stablemofusion.pipelines.timeline.TimelinePipeline` with ``impose="x0"``."""
        sampling, footskate = self._settings(guidance_scale, steps, sampler, footskate, engine)
        return self._timeline(segments, overlap, base_seed(seed), sampling, footskate, footskate_options)

    def edit(self, prompt: str, source: np.ndarray, mode: str, *, keep_start: float = 0.0, keep_end: float = 0.0,
             seconds: float | None = None, path: np.ndarray | None = None, guidance_scale: float | None = None,
             steps: int | None = None, sampler: str | None = None, seed: int | None = None, impose: str = "x0",
             footskate: str | None = None, footskate_options=None, engine: str | None = None,
             progress: bool | None = None) -> MotionResult:
        """Edit ``source`` features (Ts, D) with ``prompt``, as the torch path's
        :class:`~stablemofusion.pipelines.edit.EditPipeline` with ``impose="x0"`` (the known part imposed on every
        prediction; ``impose="xt"`` needs the torch engines)."""
        m = self.model
        # 1. check inputs; the settings of an edit (a student: at least STUDENT_EDIT_STEPS)
        check_prompt(prompt, "the prompt")
        check_edit_inputs(mode, keep_start, keep_end, seconds)
        if impose != "x0":
            raise SMFError(f"impose {impose!r} runs on the torch engines (pip install 'stablemofusion[train]'); the "
                           "portable runtime imposes on x0")
        sampling, footskate = self._settings(guidance_scale, steps, sampler, footskate, engine, edit=True)
        # 2. prepare: the plan and the seed
        seed = base_seed(seed)
        plan = plan_edit_for(mode, source, self.skeleton, self.fps, self.min_frames, self.max_frames,
                             keep_start=keep_start, keep_end=keep_end, seconds=seconds, path=path)
        # 3. denoise, exact on the known part after the last step
        tokens, mask, _ = self.encode([prompt])
        raw = sample(m, tokens, mask, [plan.frames], [seed], x0_hook=x0_constraint(plan, m.mean, m.std),
                     **sampling)[0]
        (f, motion), = finish_many([plan.project(raw.astype(np.float64)).astype(np.float32)], self.skeleton,
                                   self.fps, self.rigid, footskate, footskate_options)
        # 4. post-process: place the output like the source, splice the source's kept rigid body back in
        src = np.asarray(source, dtype=np.float64)
        if plan.anchor is not None:  # the output is placed so that its kept end is where the source has it
            a, b = plan.anchor
            motion = place_rigid_like(motion, a, headings(f)[a], root_xz(f)[a], headings(src)[b], root_xz(src)[b])
        (_, source_body), = finish_many([src], self.skeleton, self.fps, self.rigid)
        motion = splice_rigid(motion, source_body, plan)
        return MotionResult.build(prompt, rigid_to_features(motion, f, self.rigid)[1], motion, self.skeleton,
                                  self.fps, seed)

    def stream(self, prompt: str, *, guidance_scale: float | None = None, steps: int | None = None,
               sampler: str | None = None, seed: int | None = None, chunk: int = STREAM_CHUNK,
               engine: str | None = None, rewind: int = STREAM_REWIND) -> MotionStream:
        """An endless motion following ``prompt``, as the torch path's ``MotionPipeline.stream``
        (:mod:`stablemofusion.motion_stream`): windows of ``chunk`` frames, window j from ``seed + j``."""
        # 1. check inputs
        check_prompt(prompt, "the prompt")
        sampling, _ = self._settings(guidance_scale, steps, sampler, "off", engine)
        check_window(STREAM_KEEP, chunk, rewind, self.max_frames)
        # 2. prepare: the seed; the windows are sampled (sample_window) as the stream is read
        return MotionStream(self, prompt, base_seed(seed), tuple(sampling.items()), chunk, STREAM_KEEP, rewind)

    def with_guidance(self, settings: tuple, guidance: float) -> tuple:
        """A stream's ``settings`` with another guidance scale (:class:`~stablemofusion.motion_stream.WindowSampler`)."""
        check_guidance(guidance)
        return tuple({**dict(settings), "guidance": float(guidance)}.items())

    def sample_window(self, prompts: list[str], frames: int, settings: tuple, seeds: list[int],
                      known: np.ndarray | None) -> np.ndarray:
        """Stream windows (:class:`~stablemofusion.motion_stream.WindowSampler`): raw features (n, frames, D), the
        ``known`` start (n, keep, D) imposed on every x0 prediction."""
        m = self.model

        def impose(x0: np.ndarray) -> np.ndarray:
            x0 = x0.copy()
            x0[:, :known.shape[1]] = (known.astype(np.float32) - m.mean) / m.std
            return x0
        tokens, mask, _ = self.encode(prompts)
        raw = sample(m, tokens, mask, [frames] * len(prompts), list(seeds), x0_hook=None if known is None else impose,
                     **dict(settings))
        return raw.astype(np.float64)

    def _settings(self, guidance_scale: float | None, steps: int | None, sampler: str | None, footskate: str | None,
                  engine: str | None, *, edit: bool = False) -> tuple[dict, str]:
        """A call's sampling keywords (guidance, sampler, steps: the model's where None; a student's edit at least
        STUDENT_EDIT_STEPS) and footskate mode, checked as the torch path checks them."""
        m = self.model
        if engine not in (None, "auto", PORTABLE_ENGINE):
            raise SMFError(f"the portable runtime runs the engine {PORTABLE_ENGINE!r}, not {engine!r}")
        guidance = m.guidance if check_guidance(guidance_scale) is None else float(guidance_scale)
        own = max(m.steps, STUDENT_EDIT_STEPS) if edit and m.student else m.steps
        steps = own if check_steps(steps) is None else int(steps)
        if m.student and steps > m.max_steps:
            raise SMFError(f"steps must be at most {m.max_steps} for this model (a distilled student: more steps drift "
                           f"into motions no human makes), got {steps}")
        footskate = check_footskate(FOOTSKATE if footskate is None else footskate)
        if footskate not in PORTABLE_FOOTSKATE:
            raise SMFError("footskate 'loop' runs inside the torch sampler; use 'post' or 'off' here")
        return dict(guidance=guidance, sampler=sampler or m.sampler, steps=steps), footskate

    def _timeline(self, segments, overlap: float, base: int, sampling: dict, footskate: str,
                  footskate_options, explicit=None) -> MotionResult:
        m = self.model
        # 1. check inputs; 2. prepare: paths from words, the windows
        segs, paths = path_segments(segment_frames(segments, self.fps))
        windows = plan_windows(segs, self.max_frames, int(round(overlap * self.fps)), self.min_frames)
        # 3. denoise window after window, each continuing the motion so far (its last frames imposed on x0)
        out = np.zeros((0, m.dim))
        for j, w in enumerate(windows):
            frames = max(w.frames, self.min_frames)
            tokens, mask, _ = self.encode([w.prompt])
            if w.keep == 0:
                raw = sample(m, tokens, mask, [frames], [base + j], **sampling)[0]
            else:
                plan = plan_edit("prefix", out[-w.keep:], self.skeleton, keep_start=w.keep, frames=frames)
                raw = sample(m, tokens, mask, [frames], [base + j], x0_hook=x0_constraint(plan, m.mean, m.std),
                             **sampling)[0]
                raw = plan.project(raw.astype(np.float64)).astype(np.float32)  # exact on the kept part
            out = np.concatenate([out, raw[w.keep:w.keep + w.new].astype(np.float64)])
        # 4. post-process: an explicit path followed, else each segment's path bent; the final stage
        placing = None
        if explicit is not None:
            out, placing = follow(out, None, explicit, self.fps)
        else:
            out = bend_segments(out, [n for _, n in segs], paths)
        (f, motion), = finish_many([out], self.skeleton, self.fps, self.rigid, footskate, footskate_options)
        f, motion = placed(f, motion, placing, self.rigid)
        return MotionResult.build("; ".join(f"{p}:{s:g}" for p, s in segments), f, motion, self.skeleton, self.fps,
                                  base)


class _TextCache:
    """The text-cache protocol of :class:`~stablemofusion.text.known.KnownActions` over a pipeline's encoder."""

    def __init__(self, pipe: PortablePipeline):
        self.pipe = pipe
        self.encoder = SimpleNamespace(name=pipe.graphs.manifest["text_encoder"]["name"])

    def get_or_compute(self, texts: list[str]) -> tuple[np.ndarray, np.ndarray]:
        tokens, mask, _ = self.pipe.encode(list(texts))
        return tokens, mask


__all__ = ["PortablePipeline", "default_graphs_path"]
