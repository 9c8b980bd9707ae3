"""A robot's kinematics for many poses at once: each pose's body frames and joint axes from MuJoCo
(``mj_kinematics``), then the Jacobians of points on its bodies for every pose together, as numpy arrays (MuJoCo
gives one point's Jacobian of one pose per call; a retarget needs every point of every frame in each iteration).

The robot's root body has a free joint and its other joints are hinges or slides. Velocities as MuJoCo's: the free
joint's first three coordinates move the base in the world frame, the next three turn it about its own axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..motion.rotation import qmul, qnormalize
from .mj import mujoco


@dataclass(frozen=True)
class Chain:
    """What the Jacobians need of the tree: ``moves`` (B, nv) 1 where a velocity coordinate moves a body (its own
    joint's or an ancestor's), ``translating`` (nv,) the coordinates that move without turning (the free joint's
    first three, slides), ``root`` the free joint's body."""

    moves: np.ndarray
    translating: np.ndarray
    root: int

    @property
    def nv(self) -> int:
        return self.moves.shape[1]


def chain_of(model, root: int) -> Chain:
    """The :class:`Chain` of an ``MjModel`` whose free joint is on body ``root``."""
    m = model
    moves = np.zeros((m.nbody, m.nv))
    for b in range(m.nbody):
        a = b
        while a > 0:
            moves[b, m.dof_bodyid == a] = 1.0
            a = int(m.body_parentid[a])
    translating = np.array([int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_SLIDE) for j in m.dof_jntid])
    translating[:3] = True
    return Chain(moves, translating, root)


@dataclass(frozen=True)
class Poses:
    """Many poses' kinematics: each body's world rotation ``rot`` (T, B, 3, 3) and position ``pos`` (T, B, 3), each
    velocity coordinate's world axis ``axis`` (T, nv, 3) and a point on it ``origin`` (T, nv, 3), metres (the free
    joint's: the world's axes then the base's own, through the base), and ``moment`` (T, nv, 3) axis x origin."""

    rot: np.ndarray
    pos: np.ndarray
    axis: np.ndarray
    origin: np.ndarray
    moment: np.ndarray


def forward(model, data, chain: Chain, qpos: np.ndarray, each=None) -> Poses:
    """The :class:`Poses` of (T, nq) poses, computed by MuJoCo pose by pose on ``data`` (an ``MjData`` of
    ``model``); ``each(t, data)``, if given, is called with each pose's kinematics in place (to find its
    contacts, say)."""
    T = len(qpos)
    rot, pos = np.empty((T, model.nbody, 9)), np.empty((T, model.nbody, 3))
    axis, anchor = np.empty((T, model.njnt, 3)), np.empty((T, model.njnt, 3))
    q, xmat, xpos, xaxis, xanchor = data.qpos, data.xmat, data.xpos, data.xaxis, data.xanchor  # views, read once
    for t in range(T):
        q[:] = qpos[t]
        mujoco.mj_kinematics(model, data)
        rot[t], pos[t], axis[t], anchor[t] = xmat, xpos, xaxis, xanchor
        if each is not None:
            each(t, data)
    rot = rot.reshape(T, -1, 3, 3)
    base, at = rot[:, chain.root], pos[:, chain.root, None]
    axes = np.concatenate([np.broadcast_to(np.eye(3), (T, 3, 3)), np.swapaxes(base, 1, 2), axis[:, 1:]], axis=1)
    origins = np.concatenate([np.repeat(at, 6, axis=1), anchor[:, 1:]], axis=1)
    return Poses(rot, pos, axes, origins, _cross(axes, origins))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3) a x b (numpy's ``cross`` costs more than the product at these sizes)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def points(poses: Poses, bodies: np.ndarray, local: np.ndarray) -> np.ndarray:
    """(T, P, 3) world positions of (P, 3) points fixed in ``bodies`` (P,) frames."""
    return poses.pos[:, bodies] + np.einsum("tpij,pj->tpi", poses.rot[:, bodies], local)


def jacobians(chain: Chain, poses: Poses, at: np.ndarray, bodies: np.ndarray, dtype=np.float64) -> np.ndarray:
    """(T, P, 3, nv) the world-position Jacobians of points ``at`` (T, P, 3) fixed to ``bodies`` (P,) or (T, P)
    (the world body, 0: fixed, a zero Jacobian), in ``dtype``: a turning coordinate's column its world axis x
    (point - a point on the axis), a translating one's its axis."""
    T, P = at.shape[:2]
    # axis x (point - origin) = point @ skew(axis), less axis x origin: one product per pose
    a = poses.axis
    skew = np.zeros((T, 3, 3, chain.nv), dtype=dtype)  # [point component, output component, coordinate]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 0, 1] = -a[..., 2], a[..., 1], a[..., 2]
    skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 2] = -a[..., 0], -a[..., 1], a[..., 0]
    out = (at.astype(dtype) @ skew.reshape(T, 3, -1)).reshape(T, P, 3, chain.nv)
    out -= poses.moment.astype(dtype).transpose(0, 2, 1)[:, None]
    out[..., chain.translating] = np.swapaxes(a[:, None, chain.translating], 2, 3)
    out *= np.broadcast_to(chain.moves[bodies].astype(dtype), (T, P, chain.nv))[:, :, None, :]
    return out


def height_jacobians(chain: Chain, poses: Poses, at: np.ndarray, bodies: np.ndarray) -> np.ndarray:
    """(T, P, nv) the rows of :func:`jacobians` for the height (z) alone: a turning coordinate's
    (axis x (point - origin))_z, a translating one's the axis's z."""
    a = poses.axis
    out = a[:, None, :, 0] * at[..., 1:2] - a[:, None, :, 1] * at[..., 0:1] - poses.moment[:, None, :, 2]
    out[..., chain.translating] = a[:, None, chain.translating, 2]
    out *= chain.moves[bodies]
    return out


def solve_spd(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(T, n) x with a[t] @ x[t] = b[t], for (T, n, n) symmetric positive definite ``a`` and (T, n) ``b``: MuJoCo's
    Cholesky factorisation, one matrix at a time (at these sizes about twice as fast as numpy's batched LU, whose
    cost is mostly per matrix); ``a`` is left as it was."""
    factor, rhs = np.array(a, dtype=np.float64, order="C"), np.ascontiguousarray(b, dtype=np.float64)
    x = np.empty(rhs.shape)
    for t in range(len(factor)):
        mujoco.mju_cholFactor(factor[t], 0.0)
        mujoco.mju_cholSolve(x[t], factor[t], rhs[t])
    return x


def integrate(qpos: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """(T, nq) poses moved by (T, nv) velocity coordinates over unit time: the base translated in the world frame,
    turned about its own axes (the quaternion times exp(dq/2)), the joints added."""
    out = qpos.copy()
    out[:, :3] += dq[:, :3]
    w = dq[:, 3:6]
    angle = np.linalg.norm(w, axis=1, keepdims=True)
    half = np.concatenate([np.cos(angle / 2), np.sinc(angle / (2 * np.pi)) / 2 * w], axis=1)  # sin(a/2) w / a
    out[:, 3:7] = qnormalize(qmul(qpos[:, 3:7], half))
    out[:, 7:] += dq[:, 6:]
    return out
