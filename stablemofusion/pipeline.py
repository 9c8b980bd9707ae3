"""MotionPipeline: text -> motion with a trained checkpoint, in a few diffusion steps.

The four inference tricks of the paper: text embedded once per prompt and kept in an LRU cache across
calls; conditional and unconditional passes in one batched forward; half precision on GPU; an efficient
sampler (SDE DPM-Solver++ 2M with Karras sigmas, 10 steps, by default).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .diffusion.checkpoint import load_checkpoint
from .diffusion.config import CheckpointConfig
from .diffusion.engine import COMPILED_ENGINES, GRAPH_ENGINES, SolverEngine, check_engine, default_engine
from .diffusion.samplers import DEFAULT_SAMPLER, make_sampler, sampler_spec
from .diffusion.sampling import (DenoiserFn, Noise, Step, X0Hook, cfg_batched, cfg_two_pass, impute_xt,
                                 model_denoiser, replace_x0, run_diffusers, run_solver, with_x0_hook)
from .diffusion.solvers import SolverTable, solver_table
from .edit import IMPOSE, EditPlan, plan_edit, splice_rigid
from .errors import SMFError
from .models.base import TextCondition
from .motion.features import joints_from_features
from .motion.root import headings, place_like, place_rigid_like, root_xz
from .motion.rigid import DEFAULT_FIT, RigidFitConfig, RigidMotion, rigid_from_features, rigid_to_features
from .motion.skeleton import get_skeleton
from .text.frozen import sentence_embedding
from .text.known import ACTIONS_FILE, DomainCheck, KnownActions
from .text.length import WEIGHTS as LENGTH_WEIGHTS
from .text.length import LengthEstimator
from .timeline import DEFAULT_OVERLAP, plan_windows


DEFAULT_SECONDS = 4.0  # length of a motion when none is given and the model has no length estimator


class LengthClampedWarning(UserWarning):
    """A requested length was outside what the model was trained on and was clamped."""


class OutOfDomainWarning(UserWarning):
    """A prompt is far from every action the model was trained on (it is generated anyway)."""


@dataclass
class MotionResult:
    """One generated motion: features (T, D) in dataset units, joints (T, J, 3) in metres, at ``fps``; ``motion``
    the rigid body (skeleton, rotations, root path) the joints and features come from (None with the rigid
    stage off)."""

    prompt: str
    features: np.ndarray
    joints: np.ndarray
    fps: float
    seed: int | None
    motion: RigidMotion | None = None
    domain: DomainCheck | None = None  # similarity to the closest known action (models with actions.json)


def default_model_path() -> Path | None:
    """The default model shipped inside the package, if any."""
    from importlib import resources

    path = Path(str(resources.files("stablemofusion") / "assets" / "default_model"))
    return path if (path / "config.json").is_file() else None


class MotionPipeline:
    """Generate motions from text with a denoiser checkpoint. Build with :meth:`from_pretrained`."""

    def __init__(self, model, mean: np.ndarray, std: np.ndarray, config: CheckpointConfig, *,
                 device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32, text_cache_size: int = 1024,
                 rigid: RigidFitConfig | None = DEFAULT_FIT, engine: str = "auto"):
        from .text.cache import LRUTextCache
        from .text.frozen import load_text_encoder

        self.device = torch.device(device)
        self.dtype = dtype
        self.model = model.to(self.device, dtype).eval()
        self.config = config
        self.skeleton = get_skeleton(config.skeleton)
        self.fps = config.fps
        self.min_frames, self.max_frames = config.min_frames, config.max_frames
        self.mean = torch.as_tensor(mean, dtype=torch.float32)
        self.std = torch.as_tensor(std, dtype=torch.float32)
        self.schedule = config.schedule
        self.text_encoder_name = config.text_encoder
        check_engine(engine, self.device)
        self.engine = engine  # 'auto': the fastest that works here (diffusion/engine.py)
        self._tables: dict[tuple[str, int], SolverTable] = {}
        self._engines: dict[str, SolverEngine] = {}
        self._load_encoder = lambda: load_text_encoder(self.text_encoder_name).to(self.device)
        self.text_cache = LRUTextCache(_LazyEncoder(self._load_encoder), maxsize=text_cache_size)
        # the rigid final stage (docs/rigid.md); None only to measure what it changes
        self.rigid = rigid
        self.known_actions: KnownActions | None = None  # set by from_pretrained when the folder has actions.json
        self.length_estimator: LengthEstimator | None = None  # set by from_pretrained (length.safetensors)

    @classmethod
    def from_pretrained(cls, path: str | Path | None = None, *, device: str | torch.device | None = None,
                        dtype: torch.dtype | None = None, **kwargs) -> "MotionPipeline":
        """Load a checkpoint folder (or a training run folder); ``None`` = the shipped default model.
        On CUDA the model runs in float16 unless ``dtype`` says otherwise; on CPU in float32."""
        if path is None:
            path = default_model_path()
            if path is None:
                raise SMFError("no default model is shipped in this version; pass a checkpoint folder")
        device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        if dtype is None:
            dtype = torch.float16 if device.type == "cuda" else torch.float32
        ck = load_checkpoint(path)
        pipe = cls(ck.model, ck.mean, ck.std, ck.config, device=device, dtype=dtype, **kwargs)
        if (ck.path / ACTIONS_FILE).is_file():
            pipe.known_actions = KnownActions.load(ck.path / ACTIONS_FILE, pipe.text_cache)
        if (ck.path / LENGTH_WEIGHTS).is_file():
            pipe.length_estimator = LengthEstimator.load(ck.path)
            if pipe.length_estimator.config.text_encoder != ck.config.text_encoder:
                raise SMFError(f"{ck.path}: the length estimator was trained with the text encoder "
                               f"{pipe.length_estimator.config.text_encoder}, the model uses {ck.config.text_encoder}")
        return pipe

    def predict_seconds(self, prompts: str | list[str]) -> list[float]:
        """The length each prompt's motion is expected to have (seconds), from the model's length estimator
        (``smf train-length``); SMFError for a model without one."""
        prompts = [prompts] if isinstance(prompts, str) else list(prompts)
        if self.length_estimator is None:
            raise SMFError("this model has no length estimator (length.safetensors); give the length, or train one "
                           "with `smf train-length`")
        tokens, mask = self.encode_text(prompts)
        sentence = sentence_embedding(tokens.float().cpu(), mask.bool().cpu())
        frames = self.length_estimator.predict_frames(sentence).clamp(self.min_frames, self.max_frames)
        return [int(f) / self.fps for f in frames]

    def encode_text(self, prompts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """Frozen token embeddings for ``prompts`` through the LRU cache: (B, L, C), (B, L)."""
        return self.text_cache.get_or_compute(list(prompts), device=self.device)

    def frames_for(self, seconds: float | None, frames: int | None) -> int:
        """A requested duration in frames, a multiple of 4, at least the model's shortest (warning if changed);
        lengths past ``max_frames`` are kept: they are generated window by window (:meth:`timeline`)."""
        if frames is None:
            if seconds is None:
                seconds = DEFAULT_SECONDS
            if not np.isfinite(seconds) or seconds <= 0:
                raise SMFError(f"seconds must be a positive number, got {seconds}")
            frames = int(round(seconds * self.fps))
        if frames <= 0:
            raise SMFError(f"frames must be positive, got {frames}")
        n = max(frames, self.min_frames) // 4 * 4
        if n != frames:
            warnings.warn(f"length {frames} frames ({frames / self.fps:.2f} s) clamped to {n} frames "
                          f"({n / self.fps:.2f} s), the range this model was trained on", LengthClampedWarning,
                          stacklevel=3)
        return n

    @torch.no_grad()
    def __call__(self, prompts: str | list[str], *, seconds: float | list[float] | None = None,
                 frames: int | list[int] | None = None, guidance_scale: float = 2.5, steps: int = 10,
                 sampler: str = DEFAULT_SAMPLER, seed: int | list[int] | None = None, batch_size: int = 32,
                 progress: bool = False, footskate: str = "off", footskate_options=None,
                 engine: str | None = None) -> list[MotionResult]:
        """Generate one motion per prompt. ``seconds``/``frames`` may be one value or one per prompt; with
        neither, the length comes from the model's length estimator (:meth:`predict_seconds`), or is
        ``DEFAULT_SECONDS`` for a model without one.
        The same seed gives the same motions; one seed per prompt makes each motion independent of the others
        it is generated with. ``footskate``: 'off', 'post' (clean up each result) or 'loop'
        (clean up the predicted x0 in the last denoising steps, StableMoFusion*); ``footskate_options`` a
        :class:`stablemofusion.footskate.FootskateOptions`. ``engine``: 'auto', 'eager', 'fast', 'compiled' or
        'graph' (:mod:`stablemofusion.diffusion.engine`; default: the pipeline's)."""
        prompts = [prompts] if isinstance(prompts, str) else list(prompts)
        if not prompts or any(not isinstance(p, str) or not p.strip() for p in prompts):
            raise SMFError("every prompt must be a non-empty text")
        if steps < 1:
            raise SMFError(f"steps must be at least 1, got {steps}")
        if batch_size < 1:
            raise SMFError(f"batch_size must be at least 1, got {batch_size}")
        n = len(prompts)
        secs = list(seconds) if isinstance(seconds, (list, tuple)) else [seconds] * n
        frs = list(frames) if isinstance(frames, (list, tuple)) else [frames] * n
        if len(secs) != n or len(frs) != n:
            raise SMFError("give one length for all prompts or one per prompt")
        unknown = [i for i in range(n) if secs[i] is None and frs[i] is None]
        if unknown and self.length_estimator is not None:  # no length given: the model's estimate from the text
            for i, s in zip(unknown, self.predict_seconds([prompts[i] for i in unknown])):
                secs[i] = s
        lengths = [self.frames_for(s, f) for s, f in zip(secs, frs)]
        per_item = isinstance(seed, (list, tuple))
        if per_item and len(seed) != n:
            raise SMFError(f"give one seed for all prompts or one per prompt: {len(seed)} seeds for {n} prompts")
        self.engine_for(sampler, engine)  # fail early on an unknown sampler or engine
        _check_footskate(footskate)
        domains: list[DomainCheck | None] = [None] * n
        if self.known_actions is not None:
            domains = list(self.known_actions.check_many(prompts))
            for p, d in dict(zip(prompts, domains)).items():
                if d.out_of_domain:
                    warnings.warn(d.message(p), OutOfDomainWarning, stacklevel=2)
        results: list[MotionResult | None] = [None] * n
        short = [i for i in range(n) if lengths[i] <= self.max_frames]
        if len(short) < n:
            _check_long(sampler, self.max_frames / self.fps)
        for i in range(n):  # longer than one window: a one-segment timeline (no clamping)
            if lengths[i] > self.max_frames:
                item_seed = seed[i] if per_item else _fresh_seed() if seed is None else seed + i
                results[i] = self.timeline([(prompts[i], lengths[i] / self.fps)], guidance_scale=guidance_scale,
                                           steps=steps, sampler=sampler, seed=item_seed, footskate=footskate,
                                           footskate_options=footskate_options)
                results[i].prompt, results[i].domain = prompts[i], domains[i]
        starts = range(0, len(short), batch_size)
        for k, start in enumerate(tqdm(starts, desc="generate", unit="batch", disable=not progress)):
            idx = short[start:start + batch_size]
            batch_seed = [seed[i] for i in idx] if per_item else None if seed is None else seed + k
            raw = self.denoise([prompts[i] for i in idx], [lengths[i] for i in idx], guidance_scale=guidance_scale,
                               steps=steps, sampler=sampler, seed=batch_seed, footskate=footskate,
                               footskate_options=footskate_options, engine=engine)
            for j, i in enumerate(idx):
                f, motion = self.finish(raw[j, :lengths[i]].numpy(), footskate, footskate_options)
                joints = joints_from_features(f, self.skeleton) if motion is None else motion.joints()
                results[i] = MotionResult(prompts[i], f, joints, self.fps, seed[i] if per_item else batch_seed, motion,
                                          domains[i])
        return results

    @torch.no_grad()
    def timeline(self, segments: list[tuple[str, float]], *, overlap: float = DEFAULT_OVERLAP,
                 guidance_scale: float = 2.5, steps: int = 10, sampler: str = DEFAULT_SAMPLER, seed: int | None = None,
                 impose: str = "x0", footskate: str = "off", footskate_options=None) -> MotionResult:
        """One continuous motion from (prompt, seconds) segments, of any total length
        (:mod:`stablemofusion.timeline`): window after window, each continuing the last ``overlap`` seconds
        of the motion so far. ``seed`` seeds the first window; window j uses ``seed + j``."""
        segs = []
        for prompt, secs in segments:
            if not isinstance(secs, (int, float)) or not np.isfinite(secs) or secs <= 0:
                raise SMFError(f"timeline segment {prompt!r}: seconds must be a positive number, got {secs}")
            segs.append((prompt, int(round(secs * self.fps))))
        windows = plan_windows(segs, self.max_frames, int(round(overlap * self.fps)), self.min_frames)
        if len(windows) > 1:
            _check_long(sampler, self.max_frames / self.fps)
        base = _fresh_seed() if seed is None else int(seed)
        kw = dict(guidance_scale=guidance_scale, steps=steps, sampler=sampler, footskate=footskate,
                  footskate_options=footskate_options)
        out = torch.zeros(0, int(self.mean.shape[0]), dtype=torch.float64)
        for j, w in enumerate(windows):
            frames = max(w.frames, self.min_frames)
            if w.keep == 0:
                raw = self.denoise([w.prompt], [frames], seed=[base + j], **kw)[0]
            else:
                plan = plan_edit("prefix", out[-w.keep:].numpy(), self.skeleton, keep_start=w.keep, frames=frames)
                raw = self.denoise([w.prompt], [frames], seed=[base + j], edit=plan, impose=impose, **kw)[0]
            out = torch.cat([out, raw[w.keep:w.keep + w.new].double()])
        f, motion = self.finish(out.numpy(), footskate, footskate_options)
        joints = joints_from_features(f, self.skeleton) if motion is None else motion.joints()
        return MotionResult("; ".join(f"{p}:{s:g}" for p, s in segments), f, joints, self.fps, base, motion)

    @torch.no_grad()
    def edit(self, prompt: str, source: np.ndarray, mode: str, *, keep_start: float = 0.0, keep_end: float = 0.0,
             seconds: float | None = None, path: np.ndarray | None = None, guidance_scale: float = 2.5,
             steps: int = 10, sampler: str = DEFAULT_SAMPLER, seed: int | None = None, impose: str = "x0",
             footskate: str = "off", footskate_options=None) -> MotionResult:
        """Edit ``source`` features (Ts, D) (dataset units; :func:`stablemofusion.edit.source_features` converts
        joints and BVH) with ``prompt``: ``mode`` one of :data:`stablemofusion.edit.EDIT_MODES`; ``keep_start``
        / ``keep_end`` in seconds; ``seconds`` the output length (default the source's); ``path`` (T, 2) metres
        for 'trajectory' (default the source's root path). The known part is imposed at every step
        (``impose`` 'x0' or 'xt'). Returns the edited motion in the source's canonical frame."""
        if not isinstance(prompt, str) or not prompt.strip():
            raise SMFError("the prompt must be a non-empty text")
        for name, value in (("keep_start", keep_start), ("keep_end", keep_end), ("seconds", seconds)):
            if value is not None and not (np.isfinite(value) and value >= 0):
                raise SMFError(f"{name} must be a finite number of seconds >= 0, got {value}")
        seed = _fresh_seed() if seed is None else int(seed)
        plan = plan_edit(mode, source, self.skeleton, keep_start=int(round(keep_start * self.fps)),
                         keep_end=int(round(keep_end * self.fps)),
                         frames=None if seconds is None else int(round(seconds * self.fps)), path=path)
        if not self.min_frames <= plan.frames <= self.max_frames:
            raise SMFError(f"an edit of {plan.frames} frames is outside the {self.min_frames}-{self.max_frames} "
                           "frames this model generates at once")
        raw = self.denoise([prompt], [plan.frames], guidance_scale=guidance_scale, steps=steps, sampler=sampler,
                           seed=[seed], footskate=footskate, footskate_options=footskate_options,
                           edit=plan, impose=impose)
        f, motion = self.finish(raw[0].numpy(), footskate, footskate_options)
        src = np.asarray(source, dtype=np.float64)
        st, ft = torch.from_numpy(src), torch.from_numpy(f)
        anchor = None
        if plan.anchor is not None:  # the output is placed so that its kept end is where the source has it
            a, b = plan.anchor
            anchor = (a, headings(ft)[a], root_xz(ft)[a], headings(st)[b], root_xz(st)[b])
        if motion is None:
            joints = joints_from_features(f, self.skeleton)
            joints = joints if anchor is None else place_like(torch.from_numpy(joints), *anchor).numpy()
        else:
            motion = motion if anchor is None else place_rigid_like(motion, *anchor)
            motion = splice_rigid(motion, self.finish(src)[1], plan)
            joints = motion.joints()
            f = rigid_to_features(motion, f, self.rigid)[1]
        return MotionResult(prompt, f, joints, self.fps, seed, motion)

    def finish(self, features: np.ndarray, footskate: str = "off",
               footskate_options=None) -> tuple[np.ndarray, RigidMotion | None]:
        """The final stage of one motion's raw features (T, D): the rigid fit, the footskate cleanup in 'post'
        mode (on the rigid body), and the body written back as features that decode to it exactly.
        Returns (features (T, D) float64, rigid motion); with the rigid stage off (``self.rigid`` None, for
        measuring what it changes) the raw features and None."""
        _check_footskate(footskate)
        f = np.asarray(features, dtype=np.float64)
        if self.rigid is None:
            return f, None
        if footskate == "post":
            from .footskate import FootskateOptions
            from .footskate.cleanup import cleanup_features

            options = footskate_options or FootskateOptions()
            f, motion = cleanup_features(f, options.config, vgrf_model=options.vgrf_model, fps=self.fps,
                                         rigid=self.rigid)
            return f, motion
        motion = rigid_from_features(f, self.skeleton, self.rigid)
        motion, f = rigid_to_features(motion, f, self.rigid)
        return f, motion

    def sample(self, prompts: list[str], lengths: list[int], *, guidance_scale: float = 2.5, steps: int = 10,
               sampler: str = DEFAULT_SAMPLER, seed: int | list[int] | None = None, batched_cfg: bool = True,
               footskate: str = "off", footskate_options=None, engine: str | None = None) -> torch.Tensor:
        """Generate a batch: features (B, max(lengths), D) in dataset units (CPU, float32) of the final motions
        (:meth:`denoise`, then :meth:`finish` on each; frames past an item's length are zero).
        ``footskate`` 'off' | 'post' | 'loop' (see :meth:`__call__`)."""
        raw = self.denoise(prompts, lengths, guidance_scale=guidance_scale, steps=steps, sampler=sampler, seed=seed,
                           batched_cfg=batched_cfg, footskate=footskate, footskate_options=footskate_options,
                           engine=engine)
        out = torch.zeros_like(raw)
        for i, n in enumerate(lengths):
            out[i, :n] = torch.from_numpy(self.finish(raw[i, :n].numpy(), footskate, footskate_options)[0])
        return out

    def text_condition(self, prompts: list[str]) -> tuple[TextCondition, TextCondition]:
        """The model's text condition for ``prompts`` and for the dropped text (classifier-free guidance), in
        the model's dtype on its device: computed once per call, outside the denoising loop."""
        tokens, tmask = self.encode_text(prompts)
        tokens = tokens.to(self.dtype)
        B = len(prompts)
        cond = self.model.condition(tokens, tmask, torch.zeros(B, dtype=torch.bool, device=self.device))
        uncond = self.model.condition(tokens, tmask, torch.ones(B, dtype=torch.bool, device=self.device))
        return cond, uncond

    def solver(self, sampler: str, steps: int) -> SolverTable:
        """The precomputed coefficient table of a fast sampler, cached per (sampler, steps)."""
        key = (sampler, steps)
        if key not in self._tables:
            self._tables[key] = solver_table(sampler, steps, self.schedule).to(self.device, self.dtype)
        return self._tables[key]

    def engine_for(self, sampler: str, engine: str | None = None) -> str:
        """The engine a call runs with: ``engine`` (default: this pipeline's) resolved for the sampler."""
        name = engine or self.engine
        check_engine(name, self.device)
        fast = sampler_spec(sampler).fast
        if name == "auto":
            return default_engine(self.device, fast)
        if name != "eager" and not fast:
            raise SMFError(f"sampler {sampler!r} runs only with the eager engine (no precomputed form)")
        return name

    @torch.no_grad()
    def denoise(self, prompts: list[str], lengths: list[int], *, guidance_scale: float = 2.5, steps: int = 10,
                sampler: str = DEFAULT_SAMPLER, seed: int | list[int] | None = None, batched_cfg: bool = True,
                footskate: str = "off", footskate_options=None, engine: str | None = None,
                edit: EditPlan | None = None, impose: str = "x0") -> torch.Tensor:
        """Denoise a batch: the model's raw features (B, max(lengths), D) in dataset units (CPU, float32), before
        the final stage; in 'loop' mode the last predicted x0 are cleaned (rigid body) inside the loop.
        ``seed``: one seed for the batch, or one per item: then an item's result does not depend on the other
        items it is batched with (for samplers whose step takes its noise: all but ddpm).
        ``engine``: see :mod:`stablemofusion.diffusion.engine` (default: the pipeline's).
        ``edit``: a known part every item keeps (:mod:`stablemofusion.edit`), imposed in x0 or in x_t
        (``impose``); its length must be every item's length."""
        _check_footskate(footskate)
        if footskate != "off" and self.rigid is None:
            raise SMFError("the footskate cleanup works on the rigid body: it needs the rigid stage")
        if steps < 1:
            raise SMFError(f"steps must be at least 1, got {steps}")
        engine = self.engine_for(sampler, engine)
        B, T, D = len(prompts), max(lengths), int(self.mean.shape[0])
        noise = Noise(seed, lengths, D, self.device)
        mask = (torch.arange(T)[None] < torch.tensor(lengths)[:, None]).to(self.device)
        cond, uncond = self.text_condition(prompts)
        use_cfg = guidance_scale != 1.0
        if edit is not None:
            if impose not in IMPOSE:
                raise SMFError(f"impose must be one of {', '.join(IMPOSE)}, got {impose!r}")
            if set(lengths) != {edit.frames}:
                raise SMFError(f"an edit of {edit.frames} frames needs every length to be {edit.frames}, got {lengths}")
            if not sampler_spec(sampler).fast:
                raise SMFError(f"editing needs a sampler with a precomputed form, not {sampler!r}")
            engine = "fast"
        if footskate == "loop":  # a hook on x0: eager loops only (it leaves the device)
            engine = "eager" if engine == "eager" else "fast"
        if engine in COMPILED_ENGINES + GRAPH_ENGINES and batched_cfg:
            table = self.solver(sampler, steps)
            x = noise.draw() * table.init_sigma
            step_noise = noise.draw(steps) if table.stochastic else None
            x = self._engine(engine).run(cond, uncond if use_cfg else None, mask, guidance_scale, table,
                                         x.to(self.dtype), None if step_noise is None else step_noise.to(self.dtype))
        else:
            denoiser = self.guided(cond, uncond, mask, guidance_scale, batched_cfg)
            if footskate == "loop":
                denoiser = with_x0_hook(denoiser, self._footskate_hook(lengths, footskate_options))
            if engine == "eager":
                sched = make_sampler(sampler, self.schedule)
                sched.set_timesteps(steps, device=self.device)
                x = run_diffusers(denoiser, sched, sampler_spec(sampler), noise, self.dtype, B)
            else:
                table = self.solver(sampler, steps)
                eps = noise.draw().to(self.dtype)
                step_noise = noise.draw(steps).to(self.dtype) if table.stochastic else None
                x_hook = None
                if edit is not None:
                    known = self.normalise(torch.from_numpy(edit.known)).expand(B, -1, -1)
                    kmask = torch.from_numpy(edit.mask).to(self.device).expand(B, -1, -1)
                    project = self._normalised_projection(edit)
                    if impose == "x0":
                        denoiser = with_x0_hook(denoiser, replace_x0(known, kmask, project))
                    else:
                        x_hook = impute_xt(known, kmask, eps, table)
                        if project is not None:
                            denoiser = with_x0_hook(denoiser, lambda x0, step: project(x0))
                x = run_solver(denoiser, table, eps * table.init_sigma, step_noise, x_hook)
        out = x.float().cpu() * self.std + self.mean
        if edit is not None:  # exact on the known part (the last step already is, up to rounding)
            out = torch.stack([edit.project(o.double()).float() for o in out])
        return out

    def normalise(self, features: torch.Tensor) -> torch.Tensor:
        """Features (..., D) in dataset units -> the model's normalised space, dtype and device."""
        return ((features.float() - self.mean) / self.std).to(self.device, self.dtype)

    def _normalised_projection(self, edit: EditPlan):
        """The edit's root constraints as a function of normalised x0 (B, T, D), or None when it has none."""
        if edit.land is None and edit.path is None:
            return None

        def project(x0: torch.Tensor) -> torch.Tensor:
            feats = x0.double().cpu() * self.std.double() + self.mean.double()
            return self.normalise(torch.stack([edit.project(f) for f in feats]))

        return project

    def guided(self, cond: TextCondition, uncond: TextCondition, mask: torch.Tensor, scale: float,
               batched: bool = True) -> DenoiserFn:
        """The denoiser of a call: the model under the text condition, with classifier-free guidance in x0
        space (``u + scale * (c - u)``, both passes in one batch, or two) unless ``scale`` is 1."""
        if scale == 1.0:
            return model_denoiser(self.model, cond, mask)
        if batched:
            return cfg_batched(self.model, cond, uncond, mask, scale)
        return cfg_two_pass(model_denoiser(self.model, cond, mask), model_denoiser(self.model, uncond, mask), scale)

    def _engine(self, name: str) -> SolverEngine:
        if name not in self._engines:
            self._engines[name] = SolverEngine(self.model, name)
        return self._engines[name]

    def _footskate_hook(self, lengths: list[int], options) -> X0Hook:
        """The in-loop footskate cleanup as an x0 hook: on the steps ``options.in_loop`` selects."""
        from .footskate import FootskateOptions

        options = options or FootskateOptions()

        def hook(x0: torch.Tensor, step: Step) -> torch.Tensor:
            if not options.in_loop(step.index, step.count):
                return x0
            return self._clean_normalised(x0, lengths, options)

        return hook

    def _clean_normalised(self, x0: torch.Tensor, lengths: list[int], options) -> torch.Tensor:
        """Footskate cleanup (on the rigid body) of each item's first ``lengths[i]`` frames of a normalised
        prediction, on the model's device and dtype."""
        from .footskate.cleanup import cleanup_features

        feats = x0.float().cpu() * self.std + self.mean
        clean = feats.clone()
        for i, n in enumerate(lengths):
            f, _ = cleanup_features(feats[i, :n].double().numpy(), options.config, vgrf_model=options.vgrf_model,
                                    fps=self.fps, rigid=self.rigid)
            clean[i, :n] = torch.from_numpy(f).float()
        return ((clean - self.mean) / self.std).to(x0.device, x0.dtype)


FOOTSKATE_MODES = ("off", "post", "loop")


def _check_long(sampler: str, window_seconds: float) -> None:
    """Motions of several windows continue each window by editing: that needs a fast sampler."""
    if not sampler_spec(sampler).fast:
        raise SMFError(f"motions longer than {window_seconds:g} s and timelines are made window by window, which "
                       f"needs a sampler with a precomputed form, not {sampler!r}")


def _fresh_seed() -> int:
    """A random seed for a call without one (reported in its results, so the motion can be made again)."""
    return int(torch.randint(0, 2**31, (1,)))


def _check_footskate(mode: str) -> None:
    if mode not in FOOTSKATE_MODES:
        raise SMFError(f"footskate must be one of {', '.join(FOOTSKATE_MODES)}, got {mode!r}")


class _LazyEncoder:
    """Loads the frozen text encoder on first use (a fully cached pipeline never loads it)."""

    def __init__(self, load):
        self._load = load
        self._enc = None
        self.calls = 0

    def _get(self):
        if self._enc is None:
            self._enc = self._load()
        return self._enc

    def encode(self, texts: list[str]):
        self.calls += 1
        return self._get().encode(texts)

    def __getattr__(self, name):
        return getattr(self._get(), name)
