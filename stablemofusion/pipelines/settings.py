"""Sampling settings of every task: the defaults (in one place), one ``check``, one seed policy and the engine
chosen once per call."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from ..diffusion.engine import check_engine, default_engine
from ..diffusion.samplers import DEFAULT_SAMPLER, STUDENT_SAMPLER, sampler_spec
from ..errors import SMFError

# classifier-free guidance scale of a model whose config names none (a model's own: its config's ``guidance``, set by
# `smf export --guidance`; a distilled student takes the scale as input)
GUIDANCE = 2.5
STEPS = 10  # sampling steps of an ordinary model (a distilled student: its checkpoint's distil.sample_steps)
SAMPLER = DEFAULT_SAMPLER  # sampler of an ordinary model
STUDENT = STUDENT_SAMPLER  # sampler of a distilled student (multistep consistency sampling)
# steps of a distilled student when it edits a motion (at least; its own count if larger): at 1 step the kept frames
# are imposed on its only prediction, which never saw them, and seams were twice the teacher's; at 8 the v3
# student's lower-body edit held the kept upper body so closely that its legs hardly walked (docs/editing.md)
STUDENT_EDIT_STEPS = 4
BATCH_SIZE = 32  # prompts per sampling call
DEFAULT_SECONDS = 4.0  # length of a motion when none is given and the model has no length estimator
FOOTSKATE_MODES = ("off", "post", "loop")
SEED_RANGE = 2**31  # fresh seeds are drawn from [0, SEED_RANGE)


class LengthClampedWarning(UserWarning):
    """A requested length was outside what the model was trained on and was clamped."""


class OutOfDomainWarning(UserWarning):
    """A prompt is far from every action the model was trained on (it is generated anyway)."""


@dataclass(frozen=True)
class Settings:
    """How a task samples: guidance scale, steps and sampler (None: the model's, :func:`model_defaults`),
    footskate mode ('off', 'post' or 'loop') and its :class:`~stablemofusion.footskate.FootskateOptions`,
    engine (None: the pipeline's) and batch size."""

    guidance_scale: float | None = None
    steps: int | None = None
    sampler: str | None = None
    footskate: str = "off"
    footskate_options: object | None = None
    engine: str | None = None
    batch_size: int = BATCH_SIZE

    def check(self, *, rigid: bool = True) -> "Settings":
        """SMFError on a bad value (``rigid``: whether the pipeline has its rigid stage); returns self. Guidance,
        steps and sampler left None (the model's) are not checked here."""
        if self.guidance_scale is not None and not np.isfinite(self.guidance_scale):
            raise SMFError(f"guidance must be a finite number, got {self.guidance_scale}")
        if self.steps is not None and self.steps < 1:
            raise SMFError(f"steps must be at least 1, got {self.steps}")
        if self.batch_size < 1:
            raise SMFError(f"batch_size must be at least 1, got {self.batch_size}")
        if self.sampler is not None:
            sampler_spec(self.sampler)  # SMFError for an unknown sampler
        check_footskate(self.footskate)
        if self.footskate != "off" and not rigid:
            raise SMFError("the footskate cleanup works on the rigid body: it needs the rigid stage")
        return self

    def for_model(self, student_steps: int | None, guidance: float | None = None, *,
                  edit: bool = False) -> "Settings":
        """These settings with the model's defaults where they leave guidance, steps or sampler None:
        ``student_steps`` is a distilled student's step count (None for an ordinary model), ``guidance`` the
        model's default scale (its config's; None: GUIDANCE); ``edit``: for an edit."""
        scale, steps, sampler = model_defaults(student_steps, guidance, edit=edit)
        return replace(self, guidance_scale=scale if self.guidance_scale is None else self.guidance_scale,
                       steps=steps if self.steps is None else self.steps,
                       sampler=sampler if self.sampler is None else self.sampler)

    def with_engine(self, engine: str) -> "Settings":
        return replace(self, engine=engine)

    @property
    def guided(self) -> bool:
        """Whether sampling runs the unconditional pass too (classifier-free guidance); settings resolved for
        the model (:meth:`for_model`)."""
        if self.guidance_scale is None:
            raise ValueError("settings not resolved for a model: guidance_scale is None")
        return self.guidance_scale != 1.0


def model_defaults(student_steps: int | None, guidance: float | None = None, *,
                   edit: bool = False) -> tuple[float, int, str]:
    """(guidance, steps, sampler) a model samples with by default: its own guidance scale (``guidance``, from
    its config) or GUIDANCE; a distilled student (``student_steps``, from its checkpoint) its step count with
    consistency sampling (for an ``edit`` at least STUDENT_EDIT_STEPS), any other model STEPS with SAMPLER."""
    scale = GUIDANCE if guidance is None else float(guidance)
    if student_steps is None:
        return scale, STEPS, SAMPLER
    return scale, (max(int(student_steps), STUDENT_EDIT_STEPS) if edit else int(student_steps)), STUDENT


def check_footskate(mode: str) -> None:
    if mode not in FOOTSKATE_MODES:
        raise SMFError(f"footskate must be one of {', '.join(FOOTSKATE_MODES)}, got {mode!r}")


def resolve_engine(name: str, device: torch.device, sampler: str, *, hooks: bool = False) -> str:
    """The engine a call runs with, decided once: ``name`` ('auto' = the fastest that works here) for the
    sampler; calls with x0 / x_t hooks (editing, footskate in the loop) run eagerly ('eager' or 'fast')."""
    check_engine(name, device)
    fast = sampler_spec(sampler).fast
    if name == "auto":
        name = default_engine(device, fast)
    elif name != "eager" and not fast:
        raise SMFError(f"sampler {sampler!r} runs only with the eager engine (no precomputed form)")
    if hooks and name != "eager":
        return "fast"
    return name


def fresh_seed() -> int:
    """A random seed for a call without one (reported in its results, so the motion can be made again)."""
    return int(torch.randint(0, SEED_RANGE, (1,)))


def base_seed(seed: int | None) -> int:
    """The seed policy: a call's seed as given, or a fresh one (always reported in the results)."""
    return fresh_seed() if seed is None else int(seed)


def check_text(text, what: str = "the prompt") -> str:
    """A non-empty prompt, or SMFError."""
    if not isinstance(text, str) or not text.strip():
        raise SMFError(f"{what} must be a non-empty text")
    return text
