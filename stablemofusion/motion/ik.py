"""Legs placed by closed-form two-bone inverse kinematics on a rigid HumanML3D body.

Each leg is hip -> knee -> ankle -> toe. Given where its ankle and toe should be, the knee is placed in the plane
of the hip, the ankle target and the leg's own knee (so the knee points where the motion pointed it), the ankle as
close to its target as the leg reaches, and the foot turned towards its toe target. Bone lengths never change.
Where a target lies beyond the leg's reach, the pelvis moves towards it (:func:`reach_shift`), smoothly over time.
"""

from __future__ import annotations

import numpy as np

from . import timeseries as ts
from .arrays import device, namespace

# (hip, knee, ankle, toe) of the left and right leg, HumanML3D joint indices
LEGS = ((1, 4, 7, 10), (2, 5, 8, 11))
LEG_CHAIN_JOINTS = (4, 5, 7, 8, 10, 11)  # what the legs' IK places; every other joint moves with the pelvis
STRAIGHT = 0.999  # a leg is never stretched fully straight: the knee keeps a defined bend direction
EPS = 1e-9


def _unit(v):
    xp = namespace(v)
    n = xp.sqrt(xp.sum(v * v, axis=-1, keepdims=True))
    return v / xp.maximum(n, ts.const(n, EPS)), n[..., 0]


def two_bone(hip, knee, target, upper, lower):
    """Knee and ankle (..., T, 3) metres of a leg of bone lengths ``upper`` (hip-knee) and ``lower`` (knee-ankle),
    numbers or (..., 1), whose hip is at ``hip`` (..., T, 3), reaching for ``target`` (..., T, 3): the ankle at the
    target where the leg reaches it, else as far towards it as :data:`STRAIGHT` allows; the knee bent towards the
    side the input ``knee`` (..., T, 3) lies on. A leg already at its target comes back unchanged."""
    xp = namespace(hip, knee, target)
    axis, dist = _unit(target - hip)
    k = lambda v: ts.const(dist, v)  # noqa: E731
    d = xp.clip(dist, xp.abs(upper - lower) + k(1e-6), k(STRAIGHT) * (upper + lower))
    ankle = hip + axis * d[..., None]
    pole = knee - hip
    pole = pole - axis * xp.sum(pole * axis, axis=-1, keepdims=True)
    pole, _ = _unit(pole)
    along = (upper ** 2 + d ** 2 - lower ** 2) / (2 * d)
    across = xp.sqrt(xp.clip(upper ** 2 - along ** 2, 0.0, None))
    return hip + axis * along[..., None] + pole * across[..., None], ankle


def _bones(bone_lengths, j: int):
    """(B, 1) the length of the bone into joint ``j`` of lengths (B, J)."""
    return bone_lengths[:, j:j + 1]


def place_legs(joints, ankle_targets, toe_targets, bone_lengths):
    """Joints (B, T, 22, 3) with both legs re-posed: ankles towards ``ankle_targets`` (B, T, 2, 3), each foot turned
    so its toe points at ``toe_targets`` (B, T, 2, 3) (left, right); the rest of the body as it is. Bone lengths
    ``bone_lengths`` (B, 22) are kept exactly. One motion: (T, 22, 3), (T, 2, 3), (22,)."""
    xp = namespace(joints)
    if joints.ndim == 3:
        one = lambda a: a[None]  # noqa: E731
        return place_legs(one(joints), one(ankle_targets), one(toe_targets), one(bone_lengths))[0]
    placed = {}
    for k, (h, kn, a, t) in enumerate(LEGS):
        knee, ankle = two_bone(joints[:, :, h], joints[:, :, kn], ankle_targets[:, :, k], _bones(bone_lengths, kn),
                               _bones(bone_lengths, a))
        foot, _ = _unit(toe_targets[:, :, k] - ankle)
        placed[kn], placed[a], placed[t] = knee, ankle, ankle + foot * _bones(bone_lengths, t)[..., None]
    return xp.stack([placed[j] if j in placed else joints[:, :, j] for j in range(joints.shape[2])], axis=2)


def hann_window(r: int) -> np.ndarray:
    """(2r + 1,) the Hann window without its zero ends: the weights of a frame's r neighbours either side."""
    return np.hanning(2 * r + 3)[1:-1]


def reach_shift(joints, ankle_targets, bone_lengths, fps: float, smooth: float = 0.1):
    """(B, T, 3) metres: how far to move the pelvis (and the body above it) so that each leg of ``joints``
    (B, T, 22, 3) can reach its ankle target (B, T, 2, 3): the sum over both legs of the shortfall along the leg,
    spread over ``smooth`` seconds either side (so the body never jumps), and scaled so that every frame's
    shortfall is met. One motion: (T, 22, 3), (T, 2, 3), (22,) -> (T, 3)."""
    xp = namespace(joints)
    if joints.ndim == 3:
        return reach_shift(joints[None], ankle_targets[None], bone_lengths[None], fps, smooth)[0]
    need = None
    for k, (h, kn, a, _) in enumerate(LEGS):
        axis, dist = _unit(ankle_targets[:, :, k] - joints[:, :, h])
        reach = ts.const(bone_lengths, STRAIGHT * 0.995) * (_bones(bone_lengths, kn) + _bones(bone_lengths, a))
        part = axis * xp.clip(dist - reach, 0.0, None)[..., None]
        need = part if need is None else need + part
    r = max(1, int(round(smooth * fps)))
    kernel = hann_window(r)
    kernel /= kernel.max()  # a peak keeps its height: a window of max-weight 1, not of sum 1
    weights = xp.asarray(kernel, dtype=need.dtype, device=device(need))
    # a frame's shift: the need of the frames around it, whichever weighted need is largest
    best = xp.argmax(ts.windows(ts.norm(need), r) * weights, axis=-1)  # (B, T)
    picked = ts.at(need, ts.frames(need)[None] + best - r)
    return picked * xp.reshape(xp.take(weights, xp.reshape(best, (-1,))), best.shape)[..., None]


__all__ = ["LEGS", "LEG_CHAIN_JOINTS", "hann_window", "place_legs", "reach_shift", "two_bone"]
