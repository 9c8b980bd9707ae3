"""The typed configuration of a checkpoint: written by training, read by the pipeline, evaluation and bench.

``config.json`` of a checkpoint folder is ``CheckpointConfig.to_dict()``; :meth:`CheckpointConfig.from_dict`
is the one place that reads it (and fills what configs written before a field existed lack, from the
skeleton). ``from_dict(to_dict(c)) == c``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from ..core.errors import SMFError
from ..core.limits import LENGTH_MULTIPLE  # noqa: F401  (public here too)
from ..models.base import ModelConfig
from ..motion.skeleton import HUMANML3D, get_skeleton
from .schedule import ScheduleConfig



@dataclass
class TrainConfig:
    """Optimisation settings of a training run (saved in its checkpoints)."""

    preset: str = "small"
    steps: int = 50_000
    batch_size: int = 64
    lr: float = 2e-4
    weight_decay: float = 0.01
    lr_decay: float = 0.9
    lr_decay_every: int = 5_000
    grad_clip: float = 1.0
    ema_decay: float = 0.9999
    cond_drop: float = 0.1
    seed: int = 0
    mixed_precision: str = "no"  # no | fp16 | bf16
    text_encoder: str = "minilm"
    checkpoint_every: int = 1_000
    max_frames: int | None = None  # None: the corpus skeleton's
    min_frames: int | None = None  # None: the corpus skeleton's
    feat_bias: float = 5.0
    bucket: int = 0  # >0: sort each run of bucket*batch_size items by length (less padding, faster)
    text_augment: float = 0.0  # probability that a caption is perturbed (data/augment.py) before encoding
    init_from: str | None = None  # start from these weights (a checkpoint, run or exported model folder)
    compile: bool = False  # torch.compile the training forward (pays on a GPU; same numerics up to rounding)
    lr_schedule: str = "step"  # step (lr_decay every lr_decay_every) | cosine (to min_lr at `steps`) | wsd
    warmup: int = 0  # steps of linear warm-up from 0 to lr (any schedule)
    min_lr: float = 0.0  # cosine / wsd: the learning rate at the end
    decay_steps: int = 0  # wsd: the last `decay_steps` steps decay to min_lr (cosine); before them lr is constant
    balance: float = 0.0  # label balancing: an item of a (dataset, content) group of n items is drawn
    #                       round((n_max / n) ** balance) times per epoch (capped); 0 = off (needs clips.csv)
    short_crops: float = 0.0  # probability that an item is cropped to a random 50-100% of its clip (data/dataset.py)
    time_warp: float = 0.0  # probability that a batch is played slower by a factor in [1, TIME_WARP_MAX] (batches.py)
    time_warp_contents: str = "all"  # all | tempo-free: only items of the lexicon's tempo_free contents are slowed
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "TrainConfig":
        d = dict(d)
        schedule = ScheduleConfig(**d.pop("schedule", {}))
        _check_keys("train", d, TrainConfig, exclude={"schedule"})
        return TrainConfig(**d, schedule=schedule)


@dataclass
class DistilConfig:
    """Settings of a distillation run (``smf distil``), saved in the student's checkpoints: that record makes
    the folder a student (guidance as input, its own sampler and step count by default).

    ``method`` "consistency": each step draws a grid point t_{n+1} of the ``grid``-point skip schedule (the
    ``lcm`` sampler's), noises a training motion to it, runs the teacher's guided ODE step (DDIM, guidance
    w ~ U[guidance_min, guidance_max]) to the previous grid point t_n, and pulls the student's consistency
    function at (x_{t_{n+1}}, w) towards the target network's (EMA of the student, ``target_decay``) at
    (x_{t_n}, w). "regression": each step draws noise for a training batch's captions and lengths, runs the
    teacher's whole deterministic sampler from it (``teacher_sampler``, ``teacher_steps``, guidance w) and
    pulls the student's ``sample_steps``-step sample from the same noise towards it; the saved weights are
    the EMA of the student (``target_decay``). Usually from a consistency student (``init_from``); with
    ``length_mix`` some steps sample their captions at a length drawn uniformly instead of the clips'."""

    teacher: str = ""  # the teacher folder (checkpoint, run or exported model)
    method: str = "consistency"  # consistency | regression
    init_from: str | None = None  # a student folder to start from (None: the teacher's weights)
    teacher_sampler: str = "dpmsolver++-karras"  # regression: the teacher's sampler (deterministic, precomputed)
    teacher_steps: int = 10  # regression: the teacher's sampling steps
    # regression: the fraction of steps whose whole batch is sampled at one length drawn uniformly (a multiple
    # of LENGTH_MULTIPLE frames in [min_frames, max_frames]) instead of its clips' lengths: users ask for any
    # length, and a caption is otherwise only ever distilled at its clip's
    length_mix: float = 0.0
    steps: int = 4_000
    batch_size: int = 64
    lr: float = 1e-4
    weight_decay: float = 0.0
    warmup: int = 100  # linear warm-up steps; constant after
    grad_clip: float = 1.0
    target_decay: float = 0.95  # EMA of the student that gives the targets (and the saved weights)
    guidance_min: float = 1.5
    guidance_max: float = 4.0
    grid: int = 50  # skip-schedule points (must be the lcm sampler's original_inference_steps)
    loss: str = "l2"  # l2 | huber (pseudo-Huber, sqrt(d^2 + c^2) - c per feature)
    huber_c: float = 0.001
    cond_drop: float = 0.1  # fraction of items trained without text (their target is the teacher's unconditional)
    # the student's dropout layers active while distilled; off by default: the targets come from the target
    # network without dropout, so dropout's noise (about half the initial loss here) is a gap the student
    # learns to close, and the function drifts (FID rose over the first 1,000 steps of a run with it on)
    dropout: bool = False
    seed: int = 0
    mixed_precision: str = "no"  # no | fp16 | bf16
    checkpoint_every: int = 250
    bucket: int = 16  # as `smf train --bucket`
    max_frames: int | None = None  # None: the teacher's
    min_frames: int | None = None  # None: the teacher's
    sample_steps: int = 4  # the student's default sampling step count (pipelines, smf generate)
    # learning rate of the zero-initialised guidance embedding, as a multiple of ``lr``: at 1 its last layer
    # stays near zero over a short run and the student ignores the scale (docs/inference.md)
    guidance_lr_scale: float = 1.0

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "DistilConfig":
        _check_keys("distil", d, DistilConfig)
        return DistilConfig(**d)


@dataclass
class ExportInfo:
    """Where an exported (release) folder comes from."""

    from_step: int | None
    dtype: str
    version: str | None = None  # the release's name (the shipped model's: MODEL_CARD.md), in every output's metadata


@dataclass
class CheckpointConfig:
    """Everything a checkpoint needs besides its weights and Mean/Std.

    ``fps`` is the motion frame rate; ``min_frames``/``max_frames`` the length range (feature frames) the
    model was trained on; ``train`` the run's optimisation settings (None for a model built outside training);
    ``distil`` the distillation settings of a few-step student (None for an ordinary model); ``guidance`` the
    guidance scale it samples with by default (None: the package's).
    """

    model: ModelConfig
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    text_encoder: str = "minilm"
    skeleton: str = "humanml3d"
    fps: float = HUMANML3D.fps
    min_frames: int = HUMANML3D.min_frames
    max_frames: int = HUMANML3D.max_frames
    train: TrainConfig | None = None
    step: int | None = None
    export: ExportInfo | None = None
    distil: DistilConfig | None = None
    # the classifier-free guidance scale the model samples with by default (None: the package's, GUIDANCE of
    # stablemofusion.core.settings); chosen per model on held-out data and set by ``smf export --guidance``
    guidance: float | None = None

    @property
    def student(self) -> bool:
        """Whether this is a distilled few-step student (``smf distil``)."""
        return self.distil is not None

    @staticmethod
    def for_skeleton(model: ModelConfig, skeleton: str = "humanml3d", **kw) -> "CheckpointConfig":
        """A config whose frame rate and length range are the skeleton's (unless given in ``kw``)."""
        sk = get_skeleton(skeleton)
        base = {"fps": float(sk.fps), "min_frames": sk.min_frames, "max_frames": sk.max_frames}
        return CheckpointConfig(model=model, skeleton=sk.name, **{**base, **kw})

    def to_dict(self) -> dict:
        return {"model": self.model.to_dict(), "schedule": asdict(self.schedule), "text_encoder": self.text_encoder,
                "skeleton": self.skeleton, "fps": self.fps, "min_frames": self.min_frames,
                "max_frames": self.max_frames, "train": None if self.train is None else self.train.to_dict(),
                "step": self.step, "export": None if self.export is None else asdict(self.export),
                **({} if self.distil is None else {"distil": self.distil.to_dict()}),
                **({} if self.guidance is None else {"guidance": self.guidance})}

    @staticmethod
    def from_dict(d: dict[str, Any], where: str = "config") -> "CheckpointConfig":
        """Read a config.json object; raises SMFError naming ``where`` and the problem."""
        if not isinstance(d, dict):
            raise SMFError(f"{where}: not a checkpoint config (a JSON object)")
        model = d.get("model")
        if not isinstance(model, dict) or not isinstance(model.get("arch"), str) or not isinstance(
                model.get("options", {}), dict):
            raise SMFError(f"{where}: not a checkpoint config (needs an object 'model' with a string 'arch')")
        try:
            _check_keys(where, d, CheckpointConfig)
            for name in ("train", "schedule", "export", "distil"):
                if d.get(name) is not None and not isinstance(d[name], dict):
                    raise SMFError(f"{where}: '{name}' must be an object")
            train = TrainConfig.from_dict(d["train"]) if d.get("train") else None
            # configs written before the schedule had its own entry kept it in the training settings
            schedule = ScheduleConfig(**(d.get("schedule") or (d.get("train") or {}).get("schedule") or {}))
            sk = get_skeleton(d.get("skeleton", "humanml3d"))
            export = ExportInfo(**d["export"]) if d.get("export") else None
            distil = DistilConfig.from_dict(d["distil"]) if d.get("distil") else None
            given = (lambda k, default: default if d.get(k) is None else d[k])  # noqa: E731
            cfg = CheckpointConfig(
                model=ModelConfig.from_dict(model), schedule=schedule, text_encoder=str(d.get("text_encoder", "minilm")),
                skeleton=sk.name, fps=float(given("fps", sk.fps)), min_frames=int(given("min_frames", sk.min_frames)),
                max_frames=int(given("max_frames", sk.max_frames)), train=train, step=d.get("step"), export=export,
                distil=distil, guidance=check_guidance(d.get("guidance"), where))
        except (TypeError, ValueError) as e:
            raise SMFError(f"{where}: bad checkpoint config ({e})") from None
        if not (cfg.fps > 0 and 0 < cfg.min_frames <= cfg.max_frames):
            raise SMFError(f"{where}: fps must be positive and 0 < min_frames <= max_frames, got fps {cfg.fps}, "
                           f"frames {cfg.min_frames}-{cfg.max_frames}")
        return cfg

    def resume_mismatch(self, other: "CheckpointConfig") -> list[str]:
        """What differs between this run's config and a saved one in what a resumed run must keep: the
        architecture, the noise schedule, the text encoder, the skeleton and the feature normalisation.
        Everything else (steps, learning rate, checkpoint rate, ...) may change when a run is extended."""
        mine, theirs = _json(self.to_dict()), _json(other.to_dict())
        out = [k for k in ("model", "schedule", "text_encoder", "skeleton") if mine[k] != theirs[k]]
        if (self.distil is None) != (other.distil is None) or (
                self.distil and other.distil and (self.distil.teacher, self.distil.grid, self.distil.method)
                != (other.distil.teacher, other.distil.grid, other.distil.method)):
            out.append("distil (teacher, grid, method)")
        if self.train and other.train and self.train.feat_bias != other.train.feat_bias:
            out.append("feat_bias")
        return out


def check_guidance(value: Any, where: str) -> float | None:
    """A config's default guidance scale: None, or a finite number >= 0 (SMFError naming ``where`` otherwise)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise SMFError(f"{where}: 'guidance' must be a finite number >= 0, got {value!r}")
    return float(value)


def _json(d: dict) -> dict:
    """Round-trip through JSON, so tuples compare equal to the lists read back from config.json."""
    return json.loads(json.dumps(d))


def _check_keys(where: str, d: dict, cls: type, exclude: set[str] = frozenset()) -> None:
    known = {f.name for f in fields(cls)} - set(exclude)
    unknown = sorted(set(d) - known - set(exclude))
    if unknown:
        raise SMFError(f"{where}: unknown config field(s) {', '.join(unknown)}")
