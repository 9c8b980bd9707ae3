"""Legs placed by closed-form two-bone inverse kinematics on a rigid HumanML3D body.

Each leg is hip -> knee -> ankle -> toe. Given where its ankle and toe should be, the knee is placed in the plane
of the hip, the ankle target and the leg's own knee (so the knee points where the motion pointed it), the ankle as
close to its target as the leg reaches, and the foot turned towards its toe target. Bone lengths never change.
Where a target lies beyond the leg's reach, the pelvis moves towards it (:func:`reach_shift`), smoothly over time.
"""

from __future__ import annotations

import numpy as np

# (hip, knee, ankle, toe) of the left and right leg, HumanML3D joint indices
LEGS = ((1, 4, 7, 10), (2, 5, 8, 11))
LEG_CHAIN_JOINTS = (4, 5, 7, 8, 10, 11)  # what the legs' IK places; every other joint moves with the pelvis
STRAIGHT = 0.999  # a leg is never stretched fully straight: the knee keeps a defined bend direction
EPS = 1e-9


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, EPS), n[..., 0]


def two_bone(hip: np.ndarray, knee: np.ndarray, target: np.ndarray, upper: float, lower: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """Knee and ankle (T, 3) metres of a leg of bone lengths ``upper`` (hip-knee) and ``lower`` (knee-ankle) whose
    hip is at ``hip`` (T, 3), reaching for ``target`` (T, 3): the ankle at the target where the leg reaches it, else
    as far towards it as :data:`STRAIGHT` allows; the knee bent towards the side the input ``knee`` (T, 3) lies on.
    A leg already at its target comes back unchanged."""
    axis, dist = _unit(target - hip)
    d = np.clip(dist, abs(upper - lower) + 1e-6, STRAIGHT * (upper + lower))
    ankle = hip + axis * d[:, None]
    pole = knee - hip
    pole = pole - axis * np.sum(pole * axis, -1, keepdims=True)
    pole, _ = _unit(pole)
    along = (upper ** 2 + d ** 2 - lower ** 2) / (2 * d)
    across = np.sqrt(np.maximum(upper ** 2 - along ** 2, 0.0))
    return hip + axis * along[:, None] + pole * across[:, None], ankle


def place_legs(joints: np.ndarray, ankle_targets: np.ndarray, toe_targets: np.ndarray,
               bone_lengths: np.ndarray) -> np.ndarray:
    """Joints (T, 22, 3) with both legs re-posed: ankles towards ``ankle_targets`` (T, 2, 3), each foot turned so its
    toe points at ``toe_targets`` (T, 2, 3) (left, right); the rest of the body as it is. Bone lengths
    ``bone_lengths`` (22,) are kept exactly."""
    out = np.array(joints, dtype=np.float64, copy=True)
    for k, (h, kn, a, t) in enumerate(LEGS):
        knee, ankle = two_bone(out[:, h], out[:, kn], ankle_targets[:, k], float(bone_lengths[kn]),
                               float(bone_lengths[a]))
        foot, _ = _unit(toe_targets[:, k] - ankle)
        out[:, kn], out[:, a], out[:, t] = knee, ankle, ankle + foot * float(bone_lengths[t])
    return out


def hann_window(r: int) -> np.ndarray:
    """(2r + 1,) the Hann window without its zero ends: the weights of a frame's r neighbours either side."""
    return np.hanning(2 * r + 3)[1:-1]


def reach_shift(joints: np.ndarray, ankle_targets: np.ndarray, bone_lengths: np.ndarray, fps: float,
                smooth: float = 0.1) -> np.ndarray:
    """(T, 3) metres: how far to move the pelvis (and the body above it) so that each leg can reach its ankle
    target: the sum over both legs of the shortfall along the leg, spread over ``smooth`` seconds either side
    (so the body never jumps), and scaled so that every frame's shortfall is met."""
    need = np.zeros((len(joints), 3))
    for k, (h, kn, a, _) in enumerate(LEGS):
        axis, dist = _unit(ankle_targets[:, k] - joints[:, h])
        short = np.maximum(dist - STRAIGHT * 0.995 * (bone_lengths[kn] + bone_lengths[a]), 0.0)
        need += axis * short[:, None]
    if not need.any():
        return need
    r = max(1, int(round(smooth * fps)))
    kernel = hann_window(r)
    kernel /= kernel.max()  # a peak keeps its height: a window of max-weight 1, not of sum 1
    mag = np.linalg.norm(need, axis=-1)
    # a frame's shift: the need of the frames around it, whichever weighted need is largest
    pad = np.pad(need, ((r, r), (0, 0)), mode="edge")
    pmag = np.pad(mag, (r, r), mode="edge")
    idx = np.arange(len(need))[:, None] + np.arange(2 * r + 1)[None]
    score = pmag[idx] * kernel[None]
    best = np.argmax(score, axis=1)
    picked = pad[idx[np.arange(len(need)), best]] * kernel[best][:, None]
    return picked


__all__ = ["LEGS", "LEG_CHAIN_JOINTS", "hann_window", "place_legs", "reach_shift", "two_bone"]
