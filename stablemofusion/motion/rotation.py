"""Rotation helpers for quaternions (w, x, y, z), rotation matrices and the continuous 6D form.

Written once against the array API (:func:`stablemofusion.motion.arrays.namespace`), broadcasting over leading
dims: numpy in gives numpy out (same dtype), torch in gives torch out (differentiable). Angles in radians.
"""

from __future__ import annotations

import numpy as np

from . import timeseries as ts
from .arrays import Array, float64_numpy, namespace

__all__ = ["Array", "cont6d_to_matrix", "matrix_to_euler", "matrix_to_quat", "qbetween", "qinv", "qmul", "qnormalize",
           "qrot", "quat_to_cont6d", "quat_to_matrix", "yaw_quat"]

GIMBAL_COS = 1e-9  # below this |cos| of the middle angle the first and third axes coincide: the third angle is 0


def _norm(x: Array) -> Array:
    """(..., n) -> (..., 1) Euclidean length."""
    return namespace(x).linalg.vector_norm(x, axis=-1, keepdims=True)


def _cross(a: Array, b: Array) -> Array:
    """Cross product over the last dim (3), broadcasting leading dims as numpy does (any number of them)."""
    xp = namespace(a, b)
    return xp.linalg.cross(*xp.broadcast_arrays(a, b), axis=-1)


def qnormalize(q: Array) -> Array:
    """Unit quaternion(s) (..., 4)."""
    return q / _norm(q)


def qinv(q: Array) -> Array:
    """Inverse of unit quaternion(s) (..., 4): the conjugate."""
    return namespace(q).concat([q[..., :1], -q[..., 1:]], axis=-1)


def qmul(a: Array, b: Array) -> Array:
    """Hamilton product a*b of quaternions (..., 4): apply b first, then a."""
    xp = namespace(a, b)
    aw, ax, ay, az = xp.unstack(a, axis=-1)
    bw, bx, by, bz = xp.unstack(b, axis=-1)
    return xp.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def qrot(q: Array, v: Array) -> Array:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4)."""
    w, u = q[..., :1], q[..., 1:]
    uv = _cross(u, v)
    return v + 2.0 * (w * uv + _cross(u, uv))


def qbetween(v0: Array, v1: Array) -> Array:
    """Shortest-arc unit quaternion rotating direction v0 onto v1 (..., 3) -> (..., 4)."""
    xp = namespace(v0, v1)
    w = _norm(v0) * _norm(v1) + xp.sum(v0 * v1, axis=-1, keepdims=True)
    cross = _cross(v0, v1)
    return qnormalize(xp.concat([xp.broadcast_to(w, cross.shape[:-1] + (1,)), cross], axis=-1))


def quat_to_matrix(q: Array) -> Array:
    """Unit quaternions (..., 4) -> rotation matrices (..., 3, 3)."""
    xp = namespace(q)
    w, x, y, z = xp.unstack(q, axis=-1)
    return xp.stack([
        xp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        xp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        xp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) with w >= 0 (numpy, float64): the largest of
    the four squared components decides which formula is stable (Shepperd's method)."""
    m = np.asarray(m, dtype=np.float64)
    shape = m.shape[:-2]
    r = m.reshape(-1, 3, 3)
    tr = r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2]
    # 4 w^2, 4 x^2, 4 y^2, 4 z^2 (up to rounding): the largest is at least 1
    sq = np.stack([1 + tr, 1 + 2 * r[:, 0, 0] - tr, 1 + 2 * r[:, 1, 1] - tr, 1 + 2 * r[:, 2, 2] - tr], -1)
    k = np.argmax(sq, -1)
    s = np.sqrt(np.maximum(sq[np.arange(len(r)), k], 1e-300))  # 2 |component k|
    zyx = np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], -1)  # 4 w (x, y, z)
    xy, xz, yz = r[:, 0, 1] + r[:, 1, 0], r[:, 0, 2] + r[:, 2, 0], r[:, 1, 2] + r[:, 2, 1]  # 4 xy, 4 xz, 4 yz
    q = np.empty((len(r), 4))
    rows = [np.stack([s, zyx[:, 0] / s, zyx[:, 1] / s, zyx[:, 2] / s], -1) / 2,
            np.stack([zyx[:, 0] / s, s, xy / s, xz / s], -1) / 2,
            np.stack([zyx[:, 1] / s, xy / s, s, yz / s], -1) / 2,
            np.stack([zyx[:, 2] / s, xz / s, yz / s, s], -1) / 2]
    for i in range(4):
        q[k == i] = rows[i][k == i]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(shape + (4,))


@float64_numpy
def matrix_to_euler(m, order: str):
    """Rotation matrices (..., 3, 3) -> intrinsic Euler angles (..., 3) in degrees about the three distinct axes of
    ``order`` (e.g. "ZXY": R = Rz(a) Rx(b) Ry(c), as BVH channels are written); numpy (float64) or a tensor. With the
    middle angle at +-90 degrees (gimbal lock) the third is 0 and the first carries the rest: the angles still give
    R."""
    from ..core.errors import SMFError

    axes = ["XYZ".index(a) for a in order.upper()] if len(order) == 3 and set(order.upper()) <= set("XYZ") else []
    if len(set(axes)) != 3:
        raise SMFError(f"Euler order must name the three axes X, Y, Z once each, got {order!r}")
    i, j, k = axes
    s = 1.0 if (j - i) % 3 == 1 else -1.0  # +1 for the cyclic orders XYZ, YZX, ZXY
    r = m
    xp = namespace(r)
    cos_b = xp.sqrt(r[..., i, i] ** 2 + r[..., i, j] ** 2)  # |cos b| from the row that holds it (not arcsin)
    b = ts.atan2(s * r[..., i, k], cos_b)
    a = ts.atan2(-s * r[..., j, k], r[..., k, k])
    c = ts.atan2(-s * r[..., i, j], r[..., i, i])
    # gimbal lock, c = 0: R_i(a) = R R_j(b)^T, whose angle about axis i is read off its (i+1, i+2) block
    p, q = (i + 1) % 3, (i + 2) % 3
    e = [(j + 1) % 3, (j + 2) % 3]  # R_j(b)'s plane: cos b on its diagonal, sin b off it
    cb, sb = xp.cos(b), xp.sin(b)
    rj = {(j, j): 1.0, (e[0], e[0]): cb, (e[1], e[1]): cb, (e[1], e[0]): sb, (e[0], e[1]): -sb}

    def ri(u: int, v: int):  # (R R_j(b)^T)[u, v] = sum_w R[u, w] R_j(b)[v, w]
        return sum(r[..., u, w] * rj[(v, w)] for w in range(3) if (v, w) in rj)

    locked = cos_b < ts.const(cos_b, GIMBAL_COS)
    a = xp.where(locked, ts.atan2(ri(q, p), ri(p, p)), a)
    c = xp.where(locked, xp.zeros_like(c), c)
    return ts.degrees(xp.stack([a, b, c], axis=-1))


def quat_to_cont6d(q: Array) -> Array:
    """Unit quaternions (..., 4) -> continuous 6D (..., 6): the first two matrix columns, concatenated."""
    m = quat_to_matrix(q)
    return namespace(q).concat([m[..., :, 0], m[..., :, 1]], axis=-1)


def cont6d_to_matrix(d6: Array) -> Array:
    """Continuous 6D (..., 6) -> rotation matrices (..., 3, 3) by Gram-Schmidt (columns x, y, z)."""
    a, b = d6[..., 0:3], d6[..., 3:6]
    x = a / _norm(a)
    z = _cross(x, b)
    z = z / _norm(z)
    y = _cross(z, x)
    return namespace(d6).stack([x, y, z], axis=-1)


def yaw_quat(angle: Array) -> Array:
    """Quaternion (..., 4) of a rotation by ``angle`` (...) radians about +Y."""
    xp = namespace(angle)
    half = angle / 2.0
    zeros = xp.zeros_like(half)
    return xp.stack([xp.cos(half), zeros, xp.sin(half), zeros], axis=-1)
