"""Sampling settings of every task and backend (torch-free): the defaults (in one place) and one ``check``; a
backend resolves them once per call (``Backend.settings``) and the result carries them."""

from __future__ import annotations

from dataclasses import dataclass, replace

from .errors import SMFError
from .final import EngineWarning, LengthClampedWarning, OutOfDomainWarning  # noqa: F401  (public here too)
from .limits import (BATCH_SIZE, FOOTSKATE, GUIDANCE, SAMPLER, STEPS, STUDENT_EDIT_STEPS, STUDENT_SAMPLER,
                      check_batch_size, check_footskate, check_guidance, check_steps)


@dataclass(frozen=True, kw_only=True)
class Settings:
    """How a task samples: guidance scale, steps and sampler (None: the model's, :func:`model_defaults`),
    footskate mode ('off', 'post' or 'loop') and its :class:`~stablemofusion.footskate.FootskateOptions`,
    engine (None: the pipeline's) and batch size. Built with keywords; resolved once per call for the model
    (``Backend.settings`` of :mod:`stablemofusion.backends.base`: every None filled in, the engine decided),
    carried to the sampling loop as it is and by the result."""

    guidance_scale: float | None = None
    steps: int | None = None
    sampler: str | None = None
    footskate: str | None = None  # None: FOOTSKATE where the rigid stage is on, else "off"
    footskate_options: object | None = None
    engine: str | None = None
    batch_size: int = BATCH_SIZE

    def check(self, *, rigid: bool = True) -> "Settings":
        """SMFError on a bad value (``rigid``: whether the pipeline has its rigid stage); returns self. Guidance,
        steps and sampler left None (the model's) are not checked here; the sampler's name is the backend's to
        check."""
        check_guidance(self.guidance_scale)
        check_steps(self.steps)
        check_batch_size(self.batch_size)
        if self.footskate is not None:
            check_footskate(self.footskate)
        if self.footskate not in (None, "off") and not rigid:
            raise SMFError("the footskate cleanup works on the rigid body: it needs the rigid stage")
        return self

    def for_model(self, student_steps: int | None, guidance: float | None = None, *,
                  edit: bool = False, rigid: bool = True) -> "Settings":
        """These settings with the model's defaults where they leave guidance, steps or sampler None:
        ``student_steps`` is a distilled student's step count (None for an ordinary model), ``guidance`` the
        model's default scale (its config's; None: GUIDANCE); ``edit``: for an edit."""
        scale, steps, sampler = model_defaults(student_steps, guidance, edit=edit)
        return replace(self, guidance_scale=scale if self.guidance_scale is None else self.guidance_scale,
                       steps=steps if self.steps is None else self.steps,
                       sampler=sampler if self.sampler is None else self.sampler,
                       footskate=(FOOTSKATE if rigid else "off") if self.footskate is None else self.footskate)

    @property
    def resolved(self) -> bool:
        """Whether every choice is made (``Backend.settings``)."""
        return None not in (self.guidance_scale, self.steps, self.sampler, self.engine)

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
    return scale, (max(int(student_steps), STUDENT_EDIT_STEPS) if edit else int(student_steps)), STUDENT_SAMPLER
