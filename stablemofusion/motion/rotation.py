"""Rotation helpers for quaternions (w, x, y, z), rotation matrices and the continuous 6D form.

Written once in torch and broadcasting over leading dims; every function also takes numpy arrays and then
returns numpy arrays of the same dtype (:func:`stablemofusion.motion.arrays.numpy_edge`). Angles in radians.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .arrays import Array, numpy_edge

__all__ = ["Array", "cont6d_to_matrix", "matrix_to_quat", "qbetween", "qinv", "qmul", "qnormalize", "qrot",
           "quat_to_cont6d", "quat_to_matrix", "yaw_quat"]


def _norm(x: Tensor) -> Tensor:
    """(..., n) -> (..., 1) Euclidean length."""
    return torch.linalg.vector_norm(x, dim=-1, keepdim=True)


def _cross(a: Tensor, b: Tensor) -> Tensor:
    """Cross product over the last dim (3), broadcasting leading dims as numpy does (any number of them)."""
    return torch.linalg.cross(*torch.broadcast_tensors(a, b), dim=-1)


@numpy_edge
def qnormalize(q: Array) -> Array:
    """Unit quaternion(s) (..., 4)."""
    return q / _norm(q)


@numpy_edge
def qinv(q: Array) -> Array:
    """Inverse of unit quaternion(s) (..., 4): the conjugate."""
    return torch.cat([q[..., :1], -q[..., 1:]], -1)


@numpy_edge
def qmul(a: Array, b: Array) -> Array:
    """Hamilton product a*b of quaternions (..., 4): apply b first, then a."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], -1)


@numpy_edge
def qrot(q: Array, v: Array) -> Array:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4)."""
    w, u = q[..., :1], q[..., 1:]
    uv = _cross(u, v)
    return v + 2.0 * (w * uv + _cross(u, uv))


@numpy_edge
def qbetween(v0: Array, v1: Array) -> Array:
    """Shortest-arc unit quaternion rotating direction v0 onto v1 (..., 3) -> (..., 4)."""
    w = _norm(v0) * _norm(v1) + (v0 * v1).sum(-1, keepdim=True)
    return qnormalize(torch.cat([w, _cross(v0, v1)], -1))


@numpy_edge
def quat_to_matrix(q: Array) -> Array:
    """Unit quaternions (..., 4) -> rotation matrices (..., 3, 3)."""
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) with w >= 0 (numpy, float64: scipy's
    conversion)."""
    from scipy.spatial.transform import Rotation

    shape = m.shape[:-2]
    xyzw = Rotation.from_matrix(np.asarray(m, dtype=np.float64).reshape(-1, 3, 3)).as_quat()
    q = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=-1)
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(shape + (4,))


@numpy_edge
def quat_to_cont6d(q: Array) -> Array:
    """Unit quaternions (..., 4) -> continuous 6D (..., 6): the first two matrix columns, concatenated."""
    m = quat_to_matrix(q)
    return torch.cat([m[..., :, 0], m[..., :, 1]], -1)


@numpy_edge
def cont6d_to_matrix(d6: Array) -> Array:
    """Continuous 6D (..., 6) -> rotation matrices (..., 3, 3) by Gram-Schmidt (columns x, y, z)."""
    a, b = d6[..., 0:3], d6[..., 3:6]
    x = a / _norm(a)
    z = _cross(x, b)
    z = z / _norm(z)
    y = _cross(z, x)
    return torch.stack([x, y, z], -1)


@numpy_edge
def yaw_quat(angle: Array) -> Array:
    """Quaternion (..., 4) of a rotation by ``angle`` (...) radians about +Y."""
    half = angle / 2.0
    zeros = torch.zeros_like(half)
    return torch.stack([torch.cos(half), zeros, torch.sin(half), zeros], -1)
