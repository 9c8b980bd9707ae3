"""Root-path math on features: the heading and position a feature sequence integrates to, and changes of
the root velocities that make it follow a path or land somewhere (editing, long motions).

Features store the root's yaw velocity (half-angles, radians per frame, feature 0) and its XZ velocity in
the body frame (metres per frame, features 1:3); the decoder integrates them from frame 0 at the origin,
facing +Z (:func:`stablemofusion.motion.features.root_from_features`). All functions here are pure, written once
against the array API (numpy or torch, :func:`stablemofusion.motion.arrays.namespace`), take and return features
(T, D) in dataset units, and keep every other feature as it is.
"""

from __future__ import annotations

import math

import numpy as np

from .arrays import namespace
from .features import root_from_features
from .rigid import RigidMotion
from .rotation import qinv, qmul, qrot, quat_to_matrix, yaw_quat


def headings(features):
    """(..., T, D) features -> (..., T) integrated yaw half-angles (0 at frame 0)."""
    xp = namespace(features)
    yaw = features[..., 0]
    return xp.concat([xp.zeros_like(yaw[..., :1]), xp.cumulative_sum(yaw[..., :-1], axis=-1)], axis=-1)


def root_xz(features):
    """(T, D) features -> (T, 2) integrated root XZ position in metres (origin at frame 0)."""
    root = root_from_features(features)[1]
    return namespace(root).stack([root[:, 0], root[:, 2]], axis=-1)


def _to_body(angle, xz):
    """World XZ vectors (..., 2) into the body frames of half-angles ``angle`` (...): (..., 2)."""
    xp = namespace(angle, xz)
    v = xp.stack([xz[..., 0], xp.zeros_like(xz[..., 0]), xz[..., 1]], axis=-1)
    out = qrot(yaw_quat(2.0 * angle), v)
    return xp.stack([out[..., 0], out[..., 2]], axis=-1)


def follow_path(features, path):
    """Features (..., T, D) whose root XZ velocities make the root follow ``path`` (..., T, 2) metres (``path[0]``
    is frame 0's position: the origin) under the features' own headings; the last frame repeats the one before."""
    xp = namespace(features)
    steps = xp.astype(path[..., 1:, :] - path[..., :-1, :], features.dtype)  # into frame i, by frame i-1's velocity
    vel = _to_body(headings(features)[..., 1:], steps)
    vel = xp.concat([vel, vel[..., -1:, :]], axis=-2)
    return xp.concat([features[..., :1], vel, features[..., 3:]], axis=-1)


def land_at(features, start: int, frame: int, angle, xz):
    """Spread a heading and a position change evenly over the velocities of frames [start, frame) so that
    frame ``frame`` integrates to the heading of half-angle ``angle`` (by the shortest turn) and root
    position ``xz`` (2,); frames before ``start`` and the features of every frame from ``frame`` on keep
    their values."""
    if not 0 <= start < frame < len(features):
        raise ValueError(f"need 0 <= start < frame < T, got start {start}, frame {frame}, T {len(features)}")
    xp = namespace(features)
    f = features + 0  # a copy
    n = frame - start
    turn = angle - headings(f)[frame]
    turn = (turn + math.pi / 2) % math.pi - math.pi / 2  # half-angles: the same heading every pi; take the
    f[start:frame, 0] += turn / n  # shortest turn, not a full spin
    dp = (xp.astype(xz, f.dtype) - root_xz(f)[frame]) / n
    ang = headings(f)
    f[start:frame, 1:3] += _to_body(ang[start + 1:frame + 1], xp.broadcast_to(dp, (n, 2)))
    return f


def place_like(joints: np.ndarray, frame: int, angle: float, root: np.ndarray, target_angle: float,
               target_root: np.ndarray) -> np.ndarray:
    """Turn (about +Y) and move joints (T, J, 3) so that frame ``frame``, whose root is at half-angle
    ``angle`` and XZ ``root`` (2,), ends at ``target_angle`` and ``target_root`` (2,). numpy."""
    q = _turn(angle, target_angle)
    joints = np.asarray(joints, dtype=np.float64)
    shift = np.array([root[0], 0.0, root[1]], dtype=np.float64)
    moved = qrot(np.broadcast_to(q, joints.shape[:-1] + (4,)), joints - shift)
    moved[..., 0] += target_root[0]
    moved[..., 2] += target_root[1]
    return moved


def place_rigid_like(motion: RigidMotion, frame: int, angle: float, root: np.ndarray, target_angle: float,
                     target_root: np.ndarray) -> RigidMotion:
    """:func:`place_like` for a rigid motion: its root path and root rotation turned and moved the same way."""
    q = _turn(angle, target_angle)
    shift = np.array([root[0], 0.0, root[1]], dtype=np.float64)
    path = qrot(np.broadcast_to(q, (len(motion), 4)), motion.root - shift)
    path[:, 0] += float(target_root[0])
    path[:, 2] += float(target_root[1])
    rotations = motion.rotations.copy()
    rotations[:, 0] = quat_to_matrix(q) @ rotations[:, 0]
    return RigidMotion(motion.offsets, rotations, path, motion.skeleton)


def _turn(angle: float, target_angle: float) -> np.ndarray:
    """(4,) the yaw quaternion taking a body frame at half-angle ``angle`` to one at ``target_angle`` (numpy)."""
    a, b = np.asarray(float(angle)), np.asarray(float(target_angle))
    return qmul(qinv(yaw_quat(2.0 * b)), yaw_quat(2.0 * a))


__all__ = ["follow_path", "headings", "land_at", "place_like", "place_rigid_like", "root_xz"]
