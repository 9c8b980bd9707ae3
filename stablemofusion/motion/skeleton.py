"""Skeleton definitions: joint names, parents, kinematic chains and rest directions.

HumanML3D uses the first 22 SMPL joints (Y up, metres, 20 fps, the character faces +Z with its left
side towards +X). KIT-ML uses the 21-joint MMM layout at 12.5 fps (official data in millimetres).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import SMFError


@dataclass(frozen=True)
class Skeleton:
    """A fixed joint layout and the constants of its feature representation.

    ``raw_offsets[j]`` is the unit rest direction of the bone parent(j) -> j (HumanML3D's convention);
    ``bone_lengths[j]`` its target length (0 for the root), or ``None`` when no target skeleton is known.
    """

    name: str
    joint_names: tuple[str, ...]
    chains: tuple[tuple[int, ...], ...]
    raw_offsets: tuple[tuple[float, float, float], ...]
    fps: float
    feature_dim: int
    face_joints: tuple[int, int, int, int]  # right hip, left hip, right shoulder, left shoulder
    foot_left: tuple[int, int]  # ankle, toe
    foot_right: tuple[int, int]
    leg_joints: tuple[int, int]  # knee, ankle used to scale a skeleton to the target leg length
    mirror_pairs: tuple[tuple[int, int], ...]
    bone_lengths: tuple[float, ...] | None = None
    foot_velocity_threshold: float = 0.002  # squared displacement per frame (units^2) for contacts
    # motion lengths (feature frames) of the dataset convention: the official loaders keep clips of at least
    # min_frames and crop to at most max_frames; models are trained and sampled in this range
    min_frames: int = 40
    max_frames: int = 196
    lower_body: tuple[int, ...] = ()  # root, legs and feet (editing keeps or regenerates this half)

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def parents(self) -> tuple[int, ...]:
        """Parent index of each joint (-1 for the root), derived from the chains."""
        parents = [-1] * self.num_joints
        for chain in self.chains:
            for a, b in zip(chain[:-1], chain[1:]):
                parents[b] = a
        return tuple(parents)

    @property
    def offsets_array(self) -> np.ndarray:
        """(J, 3) unit rest directions as float64."""
        return np.asarray(self.raw_offsets, dtype=np.float64)

    def target_offsets(self) -> np.ndarray | None:
        """(J, 3) target rest offsets (direction * length), or None when no target skeleton is known."""
        if self.bone_lengths is None:
            return None
        return self.offsets_array * np.asarray(self.bone_lengths, dtype=np.float64)[:, None]

    @property
    def mirror_permutation(self) -> np.ndarray:
        """(J,) index array that swaps left and right joints."""
        perm = np.arange(self.num_joints)
        for a, b in self.mirror_pairs:
            perm[a], perm[b] = b, a
        return perm


HUMANML3D = Skeleton(
    name="humanml3d",
    lower_body=(0, 1, 2, 4, 5, 7, 8, 10, 11),
    joint_names=(
        "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
        "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar",
        "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
        "left_wrist", "right_wrist",
    ),
    chains=((0, 2, 5, 8, 11), (0, 1, 4, 7, 10), (0, 3, 6, 9, 12, 15), (9, 14, 17, 19, 21),
            (9, 13, 16, 18, 20)),
    raw_offsets=(
        (0, 0, 0), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, -1, 0), (0, 1, 0), (0, -1, 0),
        (0, -1, 0), (0, 1, 0), (0, 0, 1), (0, 0, 1), (0, 1, 0), (1, 0, 0), (-1, 0, 0), (0, 0, 1),
        (0, -1, 0), (0, -1, 0), (0, -1, 0), (0, -1, 0), (0, -1, 0), (0, -1, 0),
    ),
    fps=20.0,
    feature_dim=263,
    face_joints=(2, 1, 17, 16),
    foot_left=(7, 10),
    foot_right=(8, 11),
    leg_joints=(5, 8),
    mirror_pairs=((1, 2), (4, 5), (7, 8), (10, 11), (13, 14), (16, 17), (18, 19), (20, 21)),
    # The one target skeleton every HumanML3D motion is uniformed to, read off the reference
    # new_joints files (all frames of both motions agree to 5e-7 m).
    bone_lengths=(
        0.0, 0.10307397, 0.10988337, 0.13156823, 0.39362319, 0.39018815, 0.14319024, 0.43243298,
        0.42564337, 0.05736474, 0.14338179, 0.14941888, 0.21936002, 0.13748683, 0.14338281,
        0.10303925, 0.13161400, 0.12298433, 0.25683989, 0.26309186, 0.26601182, 0.26987633,
    ),
)

KIT = Skeleton(
    name="kit",
    lower_body=(0, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20),
    joint_names=(
        "root", "BP", "BT", "BLN", "BUN", "RS", "RE", "RW", "LS", "LE", "LW", "RH", "RK", "RA", "RMrot",
        "RF", "LH", "LK", "LA", "LMrot", "LF",
    ),
    chains=((0, 11, 12, 13, 14, 15), (0, 16, 17, 18, 19, 20), (0, 1, 2, 3, 4), (3, 5, 6, 7), (3, 8, 9, 10)),
    raw_offsets=(
        (0, 0, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0), (1, 0, 0), (0, -1, 0), (0, -1, 0),
        (-1, 0, 0), (0, -1, 0), (0, -1, 0), (1, 0, 0), (0, -1, 0), (0, -1, 0), (0, 0, 1), (0, 0, 1),
        (-1, 0, 0), (0, -1, 0), (0, -1, 0), (0, 0, 1), (0, 0, 1),
    ),
    fps=12.5,
    min_frames=24,
    feature_dim=251,
    face_joints=(11, 16, 5, 8),
    foot_left=(19, 20),  # KIT's right side lies towards +X (official raw offsets)
    foot_right=(14, 15),
    leg_joints=(17, 18),
    mirror_pairs=((5, 8), (6, 9), (7, 10), (11, 16), (12, 17), (13, 18), (14, 19), (15, 20)),
    bone_lengths=None,
    foot_velocity_threshold=0.05,
)

SKELETONS: dict[str, Skeleton] = {"humanml3d": HUMANML3D, "t2m": HUMANML3D, "kit": KIT}


def get_skeleton(skeleton: str | Skeleton) -> Skeleton:
    """Return a Skeleton by name ('humanml3d', 'kit') or pass one through."""
    if isinstance(skeleton, Skeleton):
        return skeleton
    try:
        return SKELETONS[skeleton.lower()]
    except (KeyError, AttributeError):
        raise SMFError(f"unknown skeleton {skeleton!r}; expected one of: humanml3d, kit") from None


def skeleton_for_shape(shape: tuple[int, ...]) -> tuple[Skeleton, str]:
    """Guess (skeleton, kind) from an array shape: kind is 'joints' (T, J, 3) or 'features' (T, D)."""
    for sk in (HUMANML3D, KIT):
        if len(shape) == 3 and shape[1:] == (sk.num_joints, 3):
            return sk, "joints"
        if len(shape) == 2 and shape[1] == sk.feature_dim:
            return sk, "features"
    raise SMFError(
        f"array of shape {tuple(shape)} is neither joints (T, 22|21, 3) nor features (T, 263|251)"
    )
