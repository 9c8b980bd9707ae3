"""Footskate cleanup: foot contacts (kinematic or from vGRF), a fast optimisation that pins planted feet,
metrics, and the UnderPressure vGRF network port (user-supplied, non-commercial weights).

Use through the pipeline: ``pipe(prompts, footskate="post" | "loop")``, or directly with
:func:`cleanup_features` / :func:`cleanup_joints`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .cleanup import CleanupConfig, CleanupResult, align_yaw_xz, cleanup_features, cleanup_features_many, cleanup_joints
from .contacts import KinematicContactConfig, contacts_from_vgrf, kinematic_contacts
from .metrics import footskate_metrics, joint_change

__all__ = [
    "CleanupConfig", "CleanupResult", "FootskateOptions", "KinematicContactConfig", "align_yaw_xz",
    "cleanup_features", "cleanup_features_many", "cleanup_joints", "contacts_from_vgrf", "footskate_metrics", "joint_change",
    "kinematic_contacts",
]


@dataclass
class FootskateOptions:
    """How the pipeline cleans motions. ``loop_steps``: in 'loop' mode cleanup is applied to the predicted
    x0 of that many final denoising steps (the model repairs, in the next step, what the optimisation
    distorted), ending ``loop_skip_last`` steps before the end (0: the last x0, which the sampler returns
    as the result, is cleaned too). ``vgrf_model``: optional (B, T, 22, 3) -> (B, T, 2, 16) callable, e.g. a
    distilled model from :func:`stablemofusion.footskate.vgrf.load_vgrf_model` (non-commercial)."""

    config: CleanupConfig = field(default_factory=CleanupConfig)
    loop_steps: int = 2
    loop_skip_last: int = 0
    vgrf_model: object | None = None

    def in_loop(self, k: int, n_steps: int) -> bool:
        """Whether step ``k`` (0-based) of ``n_steps`` gets a cleanup in 'loop' mode."""
        end = n_steps - min(self.loop_skip_last, n_steps - 1)
        return end - self.loop_steps <= k < end
