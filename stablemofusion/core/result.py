"""The one result type of every task."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..motion.features import joints_from_features
from ..motion.plausible import check_plausible
from ..motion.rigid import RigidMotion
from ..motion.skeleton import Skeleton
from ..text.known import DomainCheck
from .settings import Settings


@dataclass
class MotionResult:
    """One generated motion: features (T, D) in dataset units, joints (T, J, 3) in metres, at ``fps``; ``motion``
    the rigid body (skeleton, rotations, root path) the joints and features come from (None with the rigid
    stage off); ``seed`` the seed that makes it again; ``domain`` the closest known action (models with
    actions.json); ``settings`` the settings it was sampled with (resolved: guidance, steps, sampler, footskate,
    engine); ``sequence`` how a prompt that asks for one thing after another was split (its parts and their
    seconds, made as a timeline; None for a prompt of one part); ``warnings`` one line each of what the user should
    know (a prompt out of domain, a length clamped, a prompt split), carried into every answer."""

    prompt: str
    features: np.ndarray
    joints: np.ndarray
    fps: float
    seed: int | None
    motion: RigidMotion | None = None
    domain: DomainCheck | None = None
    settings: Settings | None = None
    sequence: list[tuple[str, float]] | None = None  # a prompt of several parts: how it was split, (part, seconds)
    warnings: list[str] = field(default_factory=list)  # what the user should know of how it was made, one line each

    @classmethod
    def build(cls, prompt: str, features: np.ndarray, motion: RigidMotion | None, skeleton: Skeleton, fps: float,
              seed: int | None, domain: DomainCheck | None = None, settings: Settings | None = None) -> "MotionResult":
        """A result whose joints come from the rigid body, or from the features without one; a motion no human
        makes is an error (:func:`~stablemofusion.motion.plausible.check_plausible`), never a result."""
        joints = joints_from_features(features, skeleton) if motion is None else motion.joints()
        check_plausible(joints, fps)
        return cls(prompt, features, joints, fps, seed, motion, domain, settings)

    @property
    def contacts(self) -> np.ndarray | None:
        """(T, 4) bool: the frames in which the footskate cleanup held each foot joint (left ankle, left toe, right
        ankle, right toe), None where no cleanup ran."""
        return None if self.motion is None else self.motion.planted

    def to_robot(self, robot: str = "g1", joint_map: str | None = None, fps: float = 50.0):
        """This motion retargeted to a humanoid robot: ``robot`` a shipped name (g1, h1) or an MJCF file,
        ``joint_map`` a JSON file of which robot site each joint drives (None: the robot's BODY_25 keypoint sites);
        a :class:`~stablemofusion.robots.retarget.RobotMotion` at ``fps`` (its ``qpos`` in MuJoCo's order). Needs
        the ``robot`` extra (MuJoCo)."""
        from ..robots.model import load_robot  # MuJoCo, an optional extra, loads only when a robot is asked for
        from ..robots.retarget import retarget

        motion = retarget(load_robot(str(robot), None if joint_map is None else str(joint_map)), self.joints,
                          self.fps, self.contacts, fps)
        motion.warnings = list(self.warnings)
        return motion

    @property
    def frames(self) -> int:
        return len(self.joints)

    @property
    def seconds(self) -> float:
        return self.frames / self.fps
