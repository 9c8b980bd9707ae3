"""Root-path math on features: the heading and position a feature sequence integrates to, and changes of
the root velocities that make it follow a path or land somewhere (editing, long motions).

Features store the root's yaw velocity (half-angles, radians per frame, feature 0) and its XZ velocity in
the body frame (metres per frame, features 1:3); the decoder integrates them from frame 0 at the origin,
facing +Z (:func:`stablemofusion.motion.features.root_from_features`). All functions here are pure, take
and return torch tensors (T, D) in dataset units, and keep every other feature as it is.
"""

from __future__ import annotations

import torch

from .features import root_from_features
from .rigid import RigidMotion
from .rotation import qinv, qmul, qrot, quat_to_matrix, yaw_quat


def headings(features: torch.Tensor) -> torch.Tensor:
    """(T, D) features -> (T,) integrated yaw half-angles (0 at frame 0)."""
    yaw = features[:, 0]
    return torch.cat([yaw.new_zeros(1), torch.cumsum(yaw[:-1], 0)])


def root_xz(features: torch.Tensor) -> torch.Tensor:
    """(T, D) features -> (T, 2) integrated root XZ position in metres (origin at frame 0)."""
    return root_from_features(features)[1][:, [0, 2]]


def _to_body(angle: torch.Tensor, xz: torch.Tensor) -> torch.Tensor:
    """World XZ vectors (N, 2) into the body frames of half-angles ``angle`` (N,): (N, 2)."""
    v = torch.stack([xz[:, 0], torch.zeros_like(xz[:, 0]), xz[:, 1]], -1)
    return qrot(yaw_quat(2.0 * angle), v)[:, [0, 2]]


def follow_path(features: torch.Tensor, path: torch.Tensor) -> torch.Tensor:
    """Set the root XZ velocities so the root follows ``path`` (T, 2) metres (``path[0]`` is frame 0's
    position: the origin) under the features' own headings; the last frame repeats the one before."""
    f = features.clone()
    ang = headings(f)
    steps = path[1:] - path[:-1]  # world step into frame i, i = 1..T-1, taken by frame i-1's velocity
    f[:-1, 1:3] = _to_body(ang[1:], steps.to(f.dtype))
    f[-1, 1:3] = f[-2, 1:3]
    return f


def land_at(features: torch.Tensor, start: int, frame: int, angle: float | torch.Tensor,
            xz: torch.Tensor) -> torch.Tensor:
    """Spread a heading and a position change evenly over the velocities of frames [start, frame) so that
    frame ``frame`` integrates to the heading of half-angle ``angle`` (by the shortest turn) and root
    position ``xz`` (2,); frames before ``start`` and the features of every frame from ``frame`` on keep
    their values."""
    if not 0 <= start < frame < len(features):
        raise ValueError(f"need 0 <= start < frame < T, got start {start}, frame {frame}, T {len(features)}")
    f = features.clone()
    n = frame - start
    turn = angle - headings(f)[frame]
    turn = (turn + torch.pi / 2) % torch.pi - torch.pi / 2  # half-angles: the same heading every pi; take the
    f[start:frame, 0] += turn / n  # shortest turn, not a full spin
    dp = (xz.to(f.dtype) - root_xz(f)[frame]) / n
    ang = headings(f)
    f[start:frame, 1:3] += _to_body(ang[start + 1:frame + 1], dp.expand(n, 2))
    return f


def place_like(joints: torch.Tensor, frame: int, angle: torch.Tensor, root: torch.Tensor,
               target_angle: torch.Tensor, target_root: torch.Tensor) -> torch.Tensor:
    """Turn (about +Y) and move joints (T, J, 3) so that frame ``frame``, whose root is at half-angle
    ``angle`` and XZ ``root`` (2,), ends at ``target_angle`` and ``target_root`` (2,)."""
    q = _turn(angle, target_angle)
    shift = joints.new_zeros(3)
    shift[[0, 2]] = root.to(joints.dtype)
    moved = qrot(q.to(joints.dtype).expand(joints.shape[:-1] + (4,)), joints - shift)
    moved[..., 0] += target_root[0]
    moved[..., 2] += target_root[1]
    return moved


def place_rigid_like(motion: RigidMotion, frame: int, angle: torch.Tensor, root: torch.Tensor,
                     target_angle: torch.Tensor, target_root: torch.Tensor) -> RigidMotion:
    """:func:`place_like` for a rigid motion: its root path and root rotation turned and moved the same way."""
    q = _turn(angle, target_angle).double()
    shift = torch.zeros(3, dtype=torch.float64)
    shift[[0, 2]] = root.double()
    path = qrot(q.expand(len(motion), 4), torch.from_numpy(motion.root) - shift)
    path[:, 0] += float(target_root[0])
    path[:, 2] += float(target_root[1])
    rotations = motion.rotations.copy()
    rotations[:, 0] = quat_to_matrix(q.numpy()) @ rotations[:, 0]
    return RigidMotion(motion.offsets, rotations, path.numpy(), motion.skeleton)


def _turn(angle: torch.Tensor, target_angle: torch.Tensor) -> torch.Tensor:
    """(4,) the yaw quaternion taking a body frame at half-angle ``angle`` to one at ``target_angle``."""
    return qmul(qinv(yaw_quat(2.0 * target_angle)), yaw_quat(2.0 * angle))
