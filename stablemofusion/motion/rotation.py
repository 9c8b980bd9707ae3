"""Rotation helpers for quaternions (w, x, y, z), rotation matrices and the continuous 6D form.

Every function works on numpy arrays and torch tensors alike and broadcasts over leading dims.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np
import torch

Array = TypeVar("Array", np.ndarray, torch.Tensor)


def _stack(xs: list, like, dim: int = -1):
    return torch.stack(xs, dim=dim) if isinstance(like, torch.Tensor) else np.stack(xs, axis=dim)


def _cross(a, b):
    return torch.cross(a, b, dim=-1) if isinstance(a, torch.Tensor) else np.cross(a, b)


def _norm(x, keepdims: bool = True):
    if isinstance(x, torch.Tensor):
        return torch.linalg.vector_norm(x, dim=-1, keepdim=keepdims)
    return np.linalg.norm(x, axis=-1, keepdims=keepdims)


def qnormalize(q: Array) -> Array:
    """Unit quaternion(s) (..., 4)."""
    return q / _norm(q)


def qinv(q: Array) -> Array:
    """Inverse of unit quaternion(s) (..., 4): the conjugate."""
    sign = q.new_tensor([1.0, -1.0, -1.0, -1.0]) if isinstance(q, torch.Tensor) else np.array([1.0, -1.0, -1.0, -1.0])
    return q * sign


def qmul(a: Array, b: Array) -> Array:
    """Hamilton product a*b of quaternions (..., 4): apply b first, then a."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return _stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], a)


def qrot(q: Array, v: Array) -> Array:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4)."""
    w = q[..., :1]
    u = q[..., 1:]
    uv = _cross(u, v)
    return v + 2.0 * (w * uv + _cross(u, uv))


def qbetween(v0: Array, v1: Array) -> Array:
    """Shortest-arc unit quaternion rotating direction v0 onto v1 (..., 3) -> (..., 4)."""
    v = _cross(v0, v1)
    w = _norm(v0) * _norm(v1) + (v0 * v1).sum(-1, keepdims=True) if not isinstance(v0, torch.Tensor) else \
        _norm(v0) * _norm(v1) + (v0 * v1).sum(-1, keepdim=True)
    cat = torch.cat if isinstance(v0, torch.Tensor) else np.concatenate
    return qnormalize(cat([w, v], -1))


def quat_to_matrix(q: Array) -> Array:
    """Unit quaternions (..., 4) -> rotation matrices (..., 3, 3)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        _stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], q),
        _stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], q),
        _stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], q),
    ]
    return _stack(rows, q, dim=-2)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) with w >= 0 (numpy)."""
    from scipy.spatial.transform import Rotation

    shape = m.shape[:-2]
    xyzw = Rotation.from_matrix(np.asarray(m, dtype=np.float64).reshape(-1, 3, 3)).as_quat()
    q = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=-1)
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(shape + (4,))


def quat_to_cont6d(q: Array) -> Array:
    """Unit quaternions (..., 4) -> continuous 6D (..., 6): the first two matrix columns, concatenated."""
    m = quat_to_matrix(q)
    cat = torch.cat if isinstance(q, torch.Tensor) else np.concatenate
    return cat([m[..., :, 0], m[..., :, 1]], -1)


def cont6d_to_matrix(d6: Array) -> Array:
    """Continuous 6D (..., 6) -> rotation matrices (..., 3, 3) by Gram-Schmidt (columns x, y, z)."""
    a, b = d6[..., 0:3], d6[..., 3:6]
    x = a / _norm(a)
    z = _cross(x, b)
    z = z / _norm(z)
    y = _cross(z, x)
    return _stack([x, y, z], d6, dim=-1)


def yaw_quat(angle: Array) -> Array:
    """Quaternion (..., 4) of a rotation by ``angle`` radians about +Y."""
    half = angle / 2.0
    zeros = half * 0.0
    lib = torch if isinstance(angle, torch.Tensor) else np
    return _stack([lib.cos(half), zeros, lib.sin(half), zeros], angle)
