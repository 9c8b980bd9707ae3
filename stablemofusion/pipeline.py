"""MotionPipeline: text -> motion with a trained checkpoint, in a few diffusion steps.

The four inference tricks of the paper: text embedded once per prompt and kept in an LRU cache across
calls; conditional and unconditional passes in one batched forward; half precision on GPU; an efficient
sampler (SDE DPM-Solver++ 2M with Karras sigmas, 10 steps, by default).
"""

from __future__ import annotations

import inspect
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .diffusion.checkpoint import load_checkpoint
from .diffusion.samplers import DEFAULT_SAMPLER, make_sampler, model_output_for
from .diffusion.schedule import ScheduleConfig
from .errors import SMFError
from .motion.features import joints_from_features
from .motion.rigid import DEFAULT_FIT, RigidFitConfig, RigidMotion, rigid_from_features, rigid_to_features
from .motion.skeleton import get_skeleton
from .text.known import ACTIONS_FILE, DomainCheck, KnownActions


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

    def __init__(self, model, mean: np.ndarray, std: np.ndarray, config: dict, *, device: str | torch.device = "cpu",
                 dtype: torch.dtype = torch.float32, text_cache_size: int = 1024,
                 rigid: RigidFitConfig | None = DEFAULT_FIT):
        from .text.cache import LRUTextCache
        from .text.frozen import load_text_encoder

        self.device = torch.device(device)
        self.dtype = dtype
        self.model = model.to(self.device, dtype).eval()
        self.config = config
        self.skeleton = get_skeleton(config.get("skeleton", "humanml3d"))
        self.fps = float(config.get("fps", self.skeleton.fps))
        self.max_frames = int(config.get("max_frames", 196))
        self.min_frames = int(config.get("min_frames") or 40)
        self.mean = torch.as_tensor(mean, dtype=torch.float32)
        self.std = torch.as_tensor(std, dtype=torch.float32)
        self.schedule = ScheduleConfig(**config.get("train", {}).get("schedule", {}))
        self.text_encoder_name = config.get("text_encoder", "minilm")
        self._load_encoder = lambda: load_text_encoder(self.text_encoder_name).to(self.device)
        self.text_cache = LRUTextCache(_LazyEncoder(self._load_encoder), maxsize=text_cache_size)
        # the rigid final stage (docs/rigid.md); None only to measure what it changes
        self.rigid = rigid
        self.known_actions: KnownActions | None = None  # set by from_pretrained when the folder has actions.json

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
        return pipe

    def encode_text(self, prompts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """Frozen token embeddings for ``prompts`` through the LRU cache: (B, L, C), (B, L)."""
        return self.text_cache.get_or_compute(list(prompts), device=self.device)

    def frames_for(self, seconds: float | None, frames: int | None) -> int:
        """Clamp a requested duration to what the model was trained on (multiple of 4), warning if changed."""
        if frames is None:
            if seconds is None:
                seconds = 4.0
            if not np.isfinite(seconds) or seconds <= 0:
                raise SMFError(f"seconds must be a positive number, got {seconds}")
            frames = int(round(seconds * self.fps))
        if frames <= 0:
            raise SMFError(f"frames must be positive, got {frames}")
        n = min(max(frames, self.min_frames), self.max_frames) // 4 * 4
        if n != frames:
            warnings.warn(f"length {frames} frames ({frames / self.fps:.2f} s) clamped to {n} frames "
                          f"({n / self.fps:.2f} s), the range this model was trained on", LengthClampedWarning,
                          stacklevel=3)
        return n

    @torch.no_grad()
    def __call__(self, prompts: str | list[str], *, seconds: float | list[float] | None = None,
                 frames: int | list[int] | None = None, guidance_scale: float = 2.5, steps: int = 10,
                 sampler: str = DEFAULT_SAMPLER, seed: int | list[int] | None = None, batch_size: int = 32,
                 progress: bool = False, footskate: str = "off", footskate_options=None) -> list[MotionResult]:
        """Generate one motion per prompt. ``seconds``/``frames`` may be one value or one per prompt.
        The same seed gives the same motions; one seed per prompt makes each motion independent of the others
        it is generated with. ``footskate``: 'off', 'post' (clean up each result) or 'loop'
        (clean up the predicted x0 in the last denoising steps, StableMoFusion*); ``footskate_options`` a
        :class:`stablemofusion.footskate.FootskateOptions`."""
        prompts = [prompts] if isinstance(prompts, str) else list(prompts)
        if not prompts or any(not isinstance(p, str) or not p.strip() for p in prompts):
            raise SMFError("every prompt must be a non-empty text")
        if steps < 1:
            raise SMFError(f"steps must be at least 1, got {steps}")
        if batch_size < 1:
            raise SMFError(f"batch_size must be at least 1, got {batch_size}")
        n = len(prompts)
        secs = seconds if isinstance(seconds, (list, tuple)) else [seconds] * n
        frs = frames if isinstance(frames, (list, tuple)) else [frames] * n
        if len(secs) != n or len(frs) != n:
            raise SMFError("give one length for all prompts or one per prompt")
        lengths = [self.frames_for(s, f) for s, f in zip(secs, frs)]
        per_item = isinstance(seed, (list, tuple))
        if per_item and len(seed) != n:
            raise SMFError(f"give one seed for all prompts or one per prompt: {len(seed)} seeds for {n} prompts")
        make_sampler(sampler, self.schedule)  # fail early on an unknown name
        _check_footskate(footskate)
        domains: list[DomainCheck | None] = [None] * n
        if self.known_actions is not None:
            domains = list(self.known_actions.check_many(prompts))
            for p, d in dict(zip(prompts, domains)).items():
                if d.out_of_domain:
                    warnings.warn(d.message(p), OutOfDomainWarning, stacklevel=2)
        results: list[MotionResult] = []
        starts = range(0, n, batch_size)
        for k, start in enumerate(tqdm(starts, desc="generate", unit="batch", disable=not progress)):
            idx = list(range(start, min(n, start + batch_size)))
            batch_seed = [seed[i] for i in idx] if per_item else None if seed is None else seed + k
            raw = self.denoise([prompts[i] for i in idx], [lengths[i] for i in idx], guidance_scale=guidance_scale,
                               steps=steps, sampler=sampler, seed=batch_seed, footskate=footskate,
                               footskate_options=footskate_options)
            for j, i in enumerate(idx):
                f, motion = self.finish(raw[j, :lengths[i]].numpy(), footskate, footskate_options)
                joints = joints_from_features(f, self.skeleton) if motion is None else motion.joints()
                results.append(MotionResult(prompts[i], f, joints, self.fps, seed[i] if per_item else batch_seed, motion,
                                            domains[i]))
        return results

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
               footskate: str = "off", footskate_options=None) -> torch.Tensor:
        """Generate a batch: features (B, max(lengths), D) in dataset units (CPU, float32) of the final motions
        (:meth:`denoise`, then :meth:`finish` on each; frames past an item's length are zero).
        ``footskate`` 'off' | 'post' | 'loop' (see :meth:`__call__`)."""
        raw = self.denoise(prompts, lengths, guidance_scale=guidance_scale, steps=steps, sampler=sampler, seed=seed,
                           batched_cfg=batched_cfg, footskate=footskate, footskate_options=footskate_options)
        out = torch.zeros_like(raw)
        for i, n in enumerate(lengths):
            out[i, :n] = torch.from_numpy(self.finish(raw[i, :n].numpy(), footskate, footskate_options)[0])
        return out

    @torch.no_grad()
    def denoise(self, prompts: list[str], lengths: list[int], *, guidance_scale: float = 2.5, steps: int = 10,
                sampler: str = DEFAULT_SAMPLER, seed: int | list[int] | None = None, batched_cfg: bool = True,
                footskate: str = "off", footskate_options=None) -> torch.Tensor:
        """Denoise a batch: the model's raw features (B, max(lengths), D) in dataset units (CPU, float32), before
        the final stage; in 'loop' mode the last predicted x0 are cleaned (rigid body) inside the loop.
        ``seed``: one seed for the batch, or one per item: then an item's result does not depend on the other
        items it is batched with, for deterministic samplers and those whose step takes its noise
        (``variance_noise``: SDE DPM-Solver++, the default); others draw an item's step noise for the batch's
        length."""
        _check_footskate(footskate)
        if footskate != "off" and self.rigid is None:
            raise SMFError("the footskate cleanup works on the rigid body: it needs the rigid stage")
        if footskate != "off":
            from .footskate import FootskateOptions

            footskate_options = footskate_options or FootskateOptions()
        B, T, D = len(prompts), max(lengths), int(self.mean.shape[0])
        sched = make_sampler(sampler, self.schedule)
        sched.set_timesteps(steps, device=self.device)
        per_item = isinstance(seed, (list, tuple))
        if per_item:  # one generator per item: an item's noise depends on its own seed and length only
            if len(seed) != B:
                raise SMFError(f"give one seed per prompt: {len(seed)} seeds for {B} prompts")
            gens = [torch.Generator().manual_seed(int(s)) for s in seed]
            x = _item_noise(gens, lengths, T, D) * sched.init_noise_sigma
        else:
            gen = torch.Generator().manual_seed(seed if seed is not None else int(torch.seed() % 2**63))
            x = torch.randn(B, T, D, generator=gen) * sched.init_noise_sigma
        x = x.to(self.device, self.dtype)
        mask = (torch.arange(T)[None] < torch.tensor(lengths)[:, None]).to(self.device)
        tokens, tmask = self.encode_text(prompts)
        tokens = tokens.to(self.dtype)
        use_cfg = guidance_scale != 1.0
        if use_cfg and batched_cfg:  # built once, so the denoiser encodes the text once per call
            drop = torch.cat([torch.zeros(B, dtype=torch.bool), torch.ones(B, dtype=torch.bool)]).to(self.device)
            tokens2, tmask2, mask2 = torch.cat([tokens, tokens]), torch.cat([tmask, tmask]), torch.cat([mask, mask])
        stochastic = "generator" in inspect.signature(sched.step).parameters
        n_steps = len(sched.timesteps)
        for k, t in enumerate(sched.timesteps):
            x_in = sched.scale_model_input(x, t)
            tt = torch.full((B,), int(t), device=self.device, dtype=torch.long)
            if use_cfg and batched_cfg:
                out = self.model(torch.cat([x_in, x_in]), torch.cat([tt, tt]), tokens2, tmask2, drop, mask2)
                x0 = out[B:] + guidance_scale * (out[:B] - out[B:])
            elif use_cfg:
                x0 = self._guided(x_in, tt, tokens, tmask, mask, guidance_scale)
            else:
                x0 = self.model(x_in, tt, tokens, tmask, None, mask)
            if footskate == "loop" and footskate_options.in_loop(k, n_steps):
                x0 = self._clean_normalised(x0, lengths, footskate_options)
            out = model_output_for(sched, x0, x, int(t))
            if stochastic and per_item and "variance_noise" in inspect.signature(sched.step).parameters:
                noise = _item_noise(gens, lengths, T, D).to(self.device, torch.float32)
                x = sched.step(out, t, x, variance_noise=noise).prev_sample
            elif stochastic and per_item:
                step_gens = [torch.Generator(device=self.device).manual_seed(int(torch.randint(0, 2**62, (1,), generator=g)))
                             for g in gens]
                x = sched.step(out, t, x, generator=step_gens).prev_sample
            elif stochastic:  # per-step noise from the call's seed, drawn on the model's device
                step_seed = int(torch.randint(0, 2**62, (1,), generator=gen))
                x = sched.step(out, t, x, generator=torch.Generator(device=self.device).manual_seed(step_seed)).prev_sample
            else:
                x = sched.step(out, t, x).prev_sample
        x = x.float().cpu()
        return x * self.std + self.mean

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

    def _guided(self, x, t, tokens, tmask, mask, scale: float) -> torch.Tensor:
        """Classifier-free guidance in x0 space, u + scale * (c - u), as two separate forward passes."""
        B = x.shape[0]
        cond = self.model(x, t, tokens, tmask, torch.zeros(B, dtype=torch.bool, device=x.device), mask)
        uncond = self.model(x, t, tokens, tmask, torch.ones(B, dtype=torch.bool, device=x.device), mask)
        return uncond + scale * (cond - uncond)


def _item_noise(gens: list[torch.Generator], lengths: list[int], T: int, D: int) -> torch.Tensor:
    """(B, T, D) standard normal noise, item i drawn from ``gens[i]`` for its own ``lengths[i]`` frames (zeros
    after), so it does not depend on the other items of the batch."""
    out = torch.zeros(len(gens), T, D)
    for i, (g, n) in enumerate(zip(gens, lengths)):
        out[i, :n] = torch.randn(n, D, generator=g)
    return out


FOOTSKATE_MODES = ("off", "post", "loop")


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
