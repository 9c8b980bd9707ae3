"""The torch backend: a loaded checkpoint (the model and its normalisation, the checkpoint config, the text cache,
the length estimator, the known actions, the rigid final stage, the per-(sampler, steps) solver tables and
engines) as the :class:`~stablemofusion.backends.base.Backend` the task pipelines run on, plus the batch-level
calls (:meth:`TorchBackend.denoise`, :meth:`TorchBackend.sample`) that benchmarks, evaluation and training use."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from ..core.folders import companion_file, model_folder
from ..core.reliability import RELIABILITY_FILE, read_reliability
from ..diffusion.checkpoint import load_checkpoint
from ..diffusion.config import CheckpointConfig
from ..diffusion.engine import SolverEngine, check_engine
from ..diffusion.sampling import DenoiserFn, guided, replace_x0
from ..diffusion.schedulers import sampler_spec
from ..diffusion.solvers import SolverTable, solver_table
from ..core.errors import SMFError
from ..models.base import TextCondition
from ..motion.rigid import DEFAULT_FIT, RigidFitConfig, RigidMotion
from ..motion.skeleton import get_skeleton
from ..text.domain import DomainDetector
from ..text.known import ACTIONS_FILE, DomainCheck, KnownActions, domains_of
from ..text.length import WEIGHTS as LENGTH_WEIGHTS
from ..text.length import LengthEstimator
from ..core.limits import FOOTSKATE_MODES, MAX_STEPS, STUDENT_MAX_STEPS
from ..core.final import finish_many, frames_for
from ..core.settings import Settings
from .base import Known
from .torch_sampling import edit_hooks, resolve_engine, sample


# the final stage's fit and cleanup run on the GPU from this many motions a call: there, on an H200 at 196 frames,
# 32 motions took 10.2 instead of 16.0 ms a motion and 256 4.8 instead of 13.4, but one took 70.8 instead of 16.2
# (its many small kernels; benchmarks/device_final_stage.py, docs/inference.md)
DEVICE_FINAL_STAGE_MIN_MOTIONS = 32


class TorchBackend:
    """A loaded checkpoint ready to sample: build with :meth:`from_pretrained`. ``rigid`` the rigid final
    stage (docs/rigid.md; None only to measure what it changes); ``engine`` the default engine (how this backend
    runs its loop: 'auto', 'eager', 'fast', 'compiled' or 'graph')."""

    name = "torch"

    def __init__(self, model, mean: np.ndarray, std: np.ndarray, config: CheckpointConfig, *,
                 device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32, text_cache_size: int = 1024,
                 rigid: RigidFitConfig | None = DEFAULT_FIT, engine: str = "auto"):
        from ..text.cache import LRUTextCache
        from ..text.frozen import encoder_name, load_text_encoder

        self.device, self.dtype = torch.device(device), dtype
        self.model = model.to(self.device, dtype).eval()
        self.config = config
        self.skeleton = get_skeleton(config.skeleton)
        self.fps, self.min_frames, self.max_frames = config.fps, config.min_frames, config.max_frames
        self.mean = torch.as_tensor(mean, dtype=torch.float32)
        self.std = torch.as_tensor(std, dtype=torch.float32)
        self.schedule = config.schedule
        self.text_encoder_name = config.text_encoder
        check_engine(engine, self.device)
        self.engine = engine
        self._tables: dict[tuple[str, int], SolverTable] = {}
        self._engines: dict[str, SolverEngine] = {}
        encoder = _LazyEncoder(lambda: load_text_encoder(self.text_encoder_name).to(self.device),
                               encoder_name(self.text_encoder_name))
        self.text_cache = LRUTextCache(encoder, maxsize=text_cache_size)
        self.rigid = rigid
        self.known_actions: KnownActions | None = None  # from the folder's actions.json
        self.reliability = None  # how well it draws each known action, from the folder's reliability.json
        self.length_estimator: LengthEstimator | None = None  # from the folder's length.safetensors
        self.adapters: tuple[str, ...] = ()  # names of the adapters merged into the weights
        self.path: Path | None = None  # the model folder it was loaded from
        self.variants: dict[str, TorchBackend] = {}  # adapted copies offered by name (add_variants), e.g. by a server

    @classmethod
    def from_pretrained(cls, path: str | Path | None = None, *, teacher: bool = False,
                        device: str | torch.device | None = None, dtype: torch.dtype | None = None,
                        adapter=None, **kwargs):
        """Load a checkpoint folder (or a training run folder); ``None`` = the shipped default model (a distilled
        student); ``teacher``: the teacher that model names instead (:func:`model_folder`). The known actions and
        the length estimator are the folder's, or for a teacher shipped inside its student's folder the
        student's (:func:`~stablemofusion.diffusion.checkpoint.companion_file`). ``adapter``: one adapter file
        (``smf adapt``) or several, merged into the weights at load (their actions join the known actions).
        On CUDA the model runs in float16 unless ``dtype`` says otherwise; on CPU in float32."""
        path = model_folder(path, teacher=teacher)
        device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        if dtype is None:
            dtype = torch.float16 if device.type == "cuda" else torch.float32
        ck = load_checkpoint(path)
        c = cls(ck.model, ck.mean, ck.std, ck.config, device=device, dtype=dtype, **kwargs)
        c.path = ck.path
        actions = companion_file(ck.path, ACTIONS_FILE)
        if actions is not None:
            c.known_actions = KnownActions.load(actions, c.text_cache, DomainDetector.load)
        c.reliability = read_reliability(companion_file(ck.path, RELIABILITY_FILE))
        length = companion_file(ck.path, LENGTH_WEIGHTS)
        if length is not None:
            c.length_estimator = LengthEstimator.load(length.parent)
            if c.length_estimator.config.text_encoder != ck.config.text_encoder:
                raise SMFError(f"{length.parent}: the length estimator was trained with the text encoder "
                               f"{c.length_estimator.config.text_encoder}, the model uses {ck.config.text_encoder}")
        return c.with_adapters(adapter) if adapter else c

    def with_adapters(self, adapters) -> "TorchBackend":
        """This model with adapters (``smf adapt`` files or loaded :class:`~stablemofusion.adapters.file.Adapter`)
        merged into a copy of its weights; text cache, length estimator and solver tables are shared. Their
        actions join the known actions. SMFError for an adapter of another base model."""
        import copy

        from ..adapters.file import load_adapters
        from ..adapters.lora import merge_into

        adapters = load_adapters(adapters)
        if not adapters:
            return self
        if self.path is None:
            raise SMFError("adapters need a model loaded from its folder (from_pretrained)")
        part = "student" if self.student else "teacher"
        model = copy.deepcopy(self.model)
        for a in adapters:
            a.check_base(part, self.path)
            merge_into(model, a.deltas(part, {n: tuple(p.shape) for n, p in model.named_parameters()}))
        new = copy.copy(self)
        new.model, new._engines, new.variants = model, {}, {}
        new.adapters = self.adapters + tuple(a.info.name for a in adapters)
        if self.known_actions is not None:
            new.known_actions = self.known_actions.with_taught([a.info.actions for a in adapters],
                                                               [[c for _, c in a.info.clips] for a in adapters])
        return new

    def add_variants(self, adapters) -> None:
        """Offer each adapter (file or loaded) as a copy of this model of its own, by the adapter's name
        (:meth:`variant`): a server serves the base model and each adapter side by side."""
        from ..adapters.file import load_adapters

        for a in load_adapters(adapters):
            if a.info.name in self.variants:
                raise SMFError(f"two adapters are named {a.info.name!r}")
            self.variants[a.info.name] = self.with_adapters([a])

    def variant(self, name: str | None) -> "TorchBackend":
        """The adapted copy named ``name`` (:meth:`add_variants`), or this model for None."""
        if name is None:
            return self
        if name not in self.variants:
            loaded = ", ".join(self.variants) or "none"
            raise SMFError(f"no adapter named {name!r} is loaded (loaded: {loaded})")
        return self.variants[name]

    @property
    def student(self) -> bool:
        """Whether the model is a distilled few-step student (guidance as input, one forward per step)."""
        return self.config.student

    def settings(self, settings: Settings | None = None, *, edit: bool = False, hooks: bool = False) -> Settings:
        """``settings`` (default: all defaults) resolved for this model, once per call: its guidance, steps and
        sampler where they are None (its config's guidance scale or GUIDANCE; a student: its distilled step count
        and consistency sampling, for an ``edit`` at least STUDENT_EDIT_STEPS), checked, and the engine decided
        (``hooks``: the call changes the steps, as edits and timelines do; footskate 'loop' does too)."""
        student_steps = self.config.distil.sample_steps if self.student else None
        rigid = self.rigid is not None
        s = (settings or Settings()).check(rigid=rigid).for_model(student_steps, self.config.guidance, edit=edit,
                                                                  rigid=rigid)
        if s.steps > self.max_steps:
            raise SMFError(f"steps must be at most {self.max_steps} for this model (a distilled student: more steps "
                           f"drift into motions no human makes), got {s.steps}; its teacher (--teacher) takes up to "
                           f"{MAX_STEPS}")
        sampler_spec(s.sampler)  # SMFError for an unknown sampler
        engine = resolve_engine(s.engine or self.engine, self.device, s.sampler,
                                hooks=hooks or s.footskate == "loop")
        return replace(s, engine=engine)

    def check_continues(self, settings: Settings, what: str) -> None:
        """SMFError unless the sampler has a precomputed form (its table loop applies the known part each step)."""
        if not sampler_spec(settings.sampler).fast:
            raise SMFError(f"{what} needs a sampler with a precomputed form, not {settings.sampler!r}")

    footskate_modes = FOOTSKATE_MODES  # the footskate modes it runs

    @property
    def version(self) -> str | None:
        """The model's version (a release's name), None for an unreleased checkpoint."""
        return self.config.export.version if self.config.export is not None else None

    @property
    def dim(self) -> int:
        """The feature size D."""
        return int(self.mean.shape[0])

    @property
    def has_length_model(self) -> bool:
        return self.length_estimator is not None

    @torch.no_grad()
    def raw_features(self, prompts: list[str], lengths: list[int], settings: Settings, seed: int | list[int], *,
                     known: Known | None = None, progress: bool = False) -> np.ndarray:
        """Raw features (B, max(lengths), D) float32 in dataset units (:func:`.torch_sampling.sample`), ``known``
        imposed through hooks built once on the model's device."""
        x0_hook = xt_hook = None
        if known is not None and known.plan is not None:
            x0_hook, xt_hook = edit_hooks(known.plan, self.mean, self.std, len(prompts), self.device, self.dtype,
                                          known.impose)
        elif known is not None:
            if known.impose != "x0":
                raise SMFError("a known start without an edit plan is imposed on x0")
            x0_hook = replace_x0(self.normalise(torch.from_numpy(known.values)),
                                 torch.from_numpy(known.mask).to(self.device))
        return sample(self, prompts, lengths, settings, seed, x0_hook=x0_hook, xt_hook=xt_hook,
                      progress=progress).numpy()

    @torch.no_grad()
    def denoise(self, prompts: list[str], lengths: list[int], *, guidance_scale: float | None = None,
                steps: int | None = None, sampler: str | None = None, seed: int | list[int] | None = None,
                batched_cfg: bool = True,
                footskate: str = "off", footskate_options=None, engine: str | None = None) -> torch.Tensor:
        """The model's raw features (B, max(lengths), D) of one batch in dataset units (CPU, float32), before
        the final stage, as a tensor (:func:`.torch_sampling.sample`); for benchmarks, evaluation and training."""
        settings = self.settings(Settings(guidance_scale=guidance_scale, steps=steps, sampler=sampler,
                                          footskate=footskate, footskate_options=footskate_options, engine=engine))
        return sample(self, prompts, lengths, settings, seed, batched_cfg=batched_cfg)

    @torch.no_grad()
    def sample(self, prompts: list[str], lengths: list[int], *, guidance_scale: float | None = None,
               steps: int | None = None, sampler: str | None = None, seed: int | list[int] | None = None,
               batched_cfg: bool = True,
               footskate: str = "off", footskate_options=None, engine: str | None = None) -> torch.Tensor:
        """Features (B, max(lengths), D) in dataset units (CPU, float32) of the final motions of one batch
        (:meth:`denoise`, then :meth:`finish` on each; frames past an item's length are zero)."""
        raw = self.denoise(prompts, lengths, guidance_scale=guidance_scale, steps=steps, sampler=sampler, seed=seed,
                           batched_cfg=batched_cfg, footskate=footskate, footskate_options=footskate_options,
                           engine=engine)
        out = torch.zeros_like(raw)
        for i, n in enumerate(lengths):
            out[i, :n] = torch.from_numpy(self.finish(raw[i, :n].numpy(), footskate, footskate_options)[0])
        return out

    def engine_for(self, sampler: str | None, engine: str | None = None) -> str:
        """The engine a call runs with: ``engine`` (default: this backend's) resolved for the sampler (None:
        the model's)."""
        return self.settings(Settings(sampler=sampler, engine=engine)).engine

    def guided(self, cond: TextCondition, uncond: TextCondition | None, mask: torch.Tensor, scale: float,
               batched: bool = True) -> DenoiserFn:
        """The model under the text condition, with classifier-free guidance unless ``scale`` is 1 (or the
        model is a student, whose ``cond`` already holds the scale and ``uncond`` is None)."""
        return guided(self.model, cond, None if scale == 1.0 else uncond, mask, scale, batched)

    @property
    def max_steps(self) -> int:
        """The most sampling steps this model takes: a distilled student's own sound range (its config's
        ``max_steps``, else STUDENT_MAX_STEPS), any other model MAX_STEPS."""
        if not self.student:
            return MAX_STEPS
        return int(getattr(self.config, "max_steps", None) or max(STUDENT_MAX_STEPS, self.config.distil.sample_steps))

    @property
    def window_seconds(self) -> float:
        """The longest motion the model makes in one sampling call (longer ones are timelines)."""
        return self.max_frames / self.fps

    def encode_text(self, prompts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """Frozen token embeddings for ``prompts`` through the LRU cache: (B, L, C), (B, L)."""
        return self.text_cache.get_or_compute(list(prompts), device=self.device)

    def text_condition(self, prompts: list[str], guidance: float | None = None, *,
                       uncond: bool = True) -> tuple[TextCondition, TextCondition | None]:
        """The model's text condition for ``prompts`` and for the dropped text (classifier-free guidance; None
        unless ``uncond``), in the model's dtype on its device. A distilled student takes ``guidance`` as
        input: its condition holds the scale and there is no dropped-text condition (None)."""
        tokens, tmask = self.encode_text(prompts)
        tokens = tokens.to(self.dtype)
        B = len(prompts)
        keep = torch.zeros(B, dtype=torch.bool, device=self.device)
        if self.model.takes_guidance:
            if guidance is None:
                raise SMFError("a distilled student needs the guidance scale")
            return self.model.condition(tokens, tmask, keep, guidance), None
        cond = self.model.condition(tokens, tmask, keep)
        if not uncond:
            return cond, None
        return cond, self.model.condition(tokens, tmask, torch.ones(B, dtype=torch.bool, device=self.device))

    def predict_seconds(self, prompts: str | list[str], levels: list[float] | None = None) -> list[float]:
        """The length each prompt's motion is expected to have (seconds), from the model's length estimator
        (``smf train-length``): its distribution's quantile at each of ``levels`` (None: the median); SMFError for a
        model without one."""
        prompts = [prompts] if isinstance(prompts, str) else list(prompts)
        if self.length_estimator is None:
            raise SMFError("this model has no length estimator (length.safetensors); give the length, or train one "
                           "with `smf train-length`")
        tokens, mask = self.encode_text(prompts)
        q = None if levels is None else torch.tensor(levels, dtype=torch.float32)
        frames = self.length_estimator.predict_frames(tokens.cpu(), mask.cpu(), q).clamp(self.min_frames,
                                                                                        self.max_frames)
        return [int(f) / self.fps for f in frames]

    def frames_for(self, seconds: float | None, frames: int | None) -> int:
        """A requested duration in frames (:func:`~stablemofusion.core.final.frames_for`); lengths past
        ``max_frames`` are kept: they are generated window by window (timelines)."""
        return frames_for(seconds, frames, self.fps, self.min_frames)

    def domains(self, prompts: list[str]) -> list[DomainCheck | None]:
        """Each prompt's closest known action (None for models without actions.json), warning once per
        out-of-domain prompt."""
        return domains_of(self.known_actions, prompts)

    def solver(self, sampler: str, steps: int) -> SolverTable:
        """The precomputed coefficient table of a fast sampler, cached per (sampler, steps)."""
        key = (sampler, steps)
        if key not in self._tables:
            self._tables[key] = solver_table(sampler, steps, self.schedule).to(self.device, self.dtype)
        return self._tables[key]

    def solver_engine(self, name: str) -> SolverEngine:
        """The engine object of ``name`` (its compiled model and captured graphs are kept)."""
        if name not in self._engines:
            self._engines[name] = SolverEngine(self.model, name)
        return self._engines[name]

    def normalise(self, features: torch.Tensor) -> torch.Tensor:
        """Features (..., D) in dataset units -> the model's normalised space, dtype and device."""
        return ((features.float() - self.mean) / self.std).to(self.device, self.dtype)

    def denormalise(self, x: torch.Tensor) -> torch.Tensor:
        """The model's normalised features (..., D) -> dataset units, float32 on the CPU."""
        return x.float().cpu() * self.std + self.mean

    def finish(self, features: np.ndarray, footskate: str = "off",
               footskate_options=None) -> tuple[np.ndarray, RigidMotion | None]:
        """The final stage of one motion's raw features (T, D): the rigid fit, the footskate cleanup in 'post'
        mode (on the rigid body), and the body written back as features that decode to it exactly.
        Returns (features (T, D) float64, rigid motion); with the rigid stage off the raw features and None."""
        return self.finish_many([features], footskate, footskate_options)[0]

    def finish_many(self, features: list[np.ndarray], footskate: str = "off",
                    footskate_options=None) -> list[tuple[np.ndarray, RigidMotion | None]]:
        """:meth:`finish` of several motions' raw features (T_i, D), their rigid fits done together (one
        vectorised fit of all their frames; each motion's result is the one it gets alone). On a GPU the fit and
        the cleanup of a large batch run there, in float64 (:meth:`final_stage_like`)."""
        return finish_many(features, self.skeleton, self.fps, self.rigid, footskate, footskate_options,
                           self.final_stage_like(len(features)))

    def final_stage_like(self, motions: int) -> torch.Tensor | None:
        """Where the final stage's fit and cleanup of ``motions`` motions run: an empty float64 tensor on this
        pipeline's GPU from :data:`DEVICE_FINAL_STAGE_MIN_MOTIONS` motions on, else None (numpy on the host)."""
        on_gpu = self.device.type == "cuda" and motions >= DEVICE_FINAL_STAGE_MIN_MOTIONS
        return torch.empty(0, dtype=torch.float64, device=self.device) if on_gpu else None


class _LazyEncoder:
    """Loads the frozen text encoder on first use (a fully cached pipeline never loads it): its ``name`` is known
    without loading it (the known actions read it to check their cached embeddings)."""

    def __init__(self, load, name: str):
        self._load = load
        self._enc = None
        self.name = name
        self.calls = 0

    def load(self):
        """The encoder, loaded now if it was not."""
        if self._enc is None:
            self._enc = self._load()
        return self._enc

    def encode(self, texts: list[str]):
        self.calls += 1
        return self.load().encode(texts)

    def __getattr__(self, name):
        return getattr(self.load(), name)
