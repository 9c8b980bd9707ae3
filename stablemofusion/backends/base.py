"""The backend seam: what a task pipeline needs of whatever runs the network. Torch-free.

A backend is a loaded model with its text side: its sizes and skeleton, the settings it resolves a request to, the
length and domain of a prompt, one sampling call (:meth:`Backend.raw_features`: raw features in dataset units, as
numpy) and the final stage.
Every task (text to motion, timeline, edit, stream) is written once against it
(:mod:`stablemofusion.pipelines`); :mod:`stablemofusion.backends.torch_backend` and
:mod:`stablemofusion.backends.onnx_backend` implement it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..core.edit_plan import EditPlan
from ..core.limits import IMPOSE
from ..core.errors import SMFError
from ..motion.rigid import RigidFitConfig, RigidMotion
from ..motion.skeleton import Skeleton
from ..core.settings import Settings
from ..text.known import DomainCheck


@dataclass(frozen=True)
class Known:
    """What a sampling call keeps: ``values`` (B, T, D) features in dataset units imposed where ``mask`` (B, T, D)
    is True, at every step (``impose`` 'x0': on the model's prediction; 'xt': on the noisy sample, a torch-only
    way); ``plan`` an edit whose root constraints are projected on every prediction too (its known part is
    ``values``)."""

    values: np.ndarray
    mask: np.ndarray
    plan: EditPlan | None = None
    impose: str = "x0"

    def __post_init__(self):
        if self.impose not in IMPOSE:
            raise SMFError(f"impose must be one of {', '.join(IMPOSE)}, got {self.impose!r}")

    @classmethod
    def of_plan(cls, plan: EditPlan, impose: str = "x0") -> "Known":
        """The known part and root constraints of one edit (a batch of one)."""
        return cls(plan.known[None], plan.mask[None], plan, impose)

    @classmethod
    def prefix(cls, start: np.ndarray, frames: int) -> "Known":
        """Windows (n, frames, D) whose first ``start.shape[1]`` frames are ``start`` (n, keep, D), whole."""
        values = np.zeros((start.shape[0], frames, start.shape[2]))
        values[:, :start.shape[1]] = start
        mask = np.zeros(values.shape, bool)
        mask[:, :start.shape[1]] = True
        return cls(values, mask)


class Backend(Protocol):
    """A loaded model as the task pipelines see it. ``name`` 'torch' or 'onnx'; ``dim`` the feature size D;
    ``rigid`` the rigid final stage (None: off); ``student`` whether it is a distilled few-step student."""

    name: str
    skeleton: Skeleton
    fps: float
    min_frames: int
    max_frames: int
    dim: int
    rigid: RigidFitConfig | None
    student: bool
    has_length_model: bool
    version: str | None  # the model's version (a release's name)
    footskate_modes: tuple[str, ...]  # the footskate modes it runs
    adapters: tuple[str, ...]  # names of the adapters merged into its weights
    reliability: dict | None  # how well it draws each known action (core.reliability), None where not measured

    def settings(self, settings: Settings | None = None, *, edit: bool = False, hooks: bool = False) -> Settings:
        """``settings`` resolved once for this model: every None filled in from its defaults, checked, the engine
        decided. ``edit``: for an edit (a student samples it with more steps); ``hooks``: the call keeps a known
        part (edits, timelines, streams)."""

    def check_continues(self, settings: Settings, what: str) -> None:
        """SMFError unless resolved ``settings`` can keep a known part at every step (``what`` names the task)."""

    def predict_seconds(self, prompts: str | list[str], levels: list[float] | None = None) -> list[float]:
        """Each prompt's length in seconds (one text is one prompt): the length model's quantile at each of
        ``levels`` (:func:`~stablemofusion.core.noise.length_level`; None: the median); SMFError without a length
        model."""

    def domains(self, prompts: list[str]) -> list[DomainCheck | None]:
        """Each prompt's closest known action (None without known actions), warning once per out-of-domain one."""

    def raw_features(self, prompts: list[str], lengths: list[int], settings: Settings, seed: int | list[int], *,
               known: Known | None = None, progress: bool = False) -> np.ndarray:
        """Raw features (B, max(lengths), D) float32 in dataset units, before the final stage; item k draws its
        noise from ``seed`` (stream k) or ``seed[k]`` (:mod:`stablemofusion.core.noise`); ``known`` imposed."""

    def finish_many(self, features: list[np.ndarray], footskate: str = "off",
                    footskate_options=None) -> list[tuple[np.ndarray, RigidMotion | None]]:
        """The final stage of motions' raw features (T_i, D) (:func:`stablemofusion.core.final.finish_many`)."""


__all__ = ["Backend", "Known"]
