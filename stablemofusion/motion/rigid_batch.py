"""The rigid fit of many motions at once: closed form, block sweeps, pose, all vectorised over every frame.

:func:`fit_joints` and :func:`pose_joints` work on motions of one length (B, T, J, 3), are written against the
array API without a loop over frames or motions, and are the graphs ``rigid.onnx`` and ``pose.onnx`` that the
page, Node.js and game engines run (``smf export --final-stage``). :func:`fit_bodies` and :func:`pose_of_joints`
take the frames of motions of any lengths stacked (N, J, 3) with ``starts``, the first frame of each, and run
those functions on the motions of each length together. Apart from per-motion means (the rest offsets of a
branching joint's children), every frame is computed on its own, so a motion's result does not depend on what
it is stacked with.

The fit minimises the summed squared distance of every joint to its target over one rigid skeleton (fixed
bone lengths) by exact block-coordinate sweeps, top down:

- the root: the whole body moves by the mean residual of all joints;
- a branching joint (pelvis, upper spine): its children's offsets turn rigidly about it by the rotation
  that best carries them onto where their subtrees want them (a weighted orthogonal Procrustes problem,
  solved by the polar factor, :func:`polar_rotation`), their subtrees translating along;
- every other bone (its parent has one child): it points at the mean of where its subtree wants its end
  joint, the subtree translating along.

Each step is the exact minimiser over its block, so the error never grows; bones of one depth have
disjoint subtrees and move together. This is the parametrisation of the L-BFGS fit
(:func:`stablemofusion.motion.rigid.optimise_pose`), solved block by block instead of by line searches.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..core.errors import SMFError
from .arrays import device, namespace, on_like, to_numpy
from .kinematics import forward_kinematics
from .rotation import quat_to_matrix
from .skeleton import Skeleton, get_skeleton
from .timeseries import const

EPS = 1e-12  # guards divisions by a length (m) that is zero only for degenerate input
POLAR_STEPS = 8  # scaled Newton steps of the polar decomposition: converged to 1e-15 for any branch here


@dataclass(frozen=True)
class Tree:
    """A skeleton's kinematic tree as index arrays: ``parents`` (J,), ``subtree`` (J, J) with
    ``subtree[c, k]`` 1 where k is c or below it, ``branches`` the joints with several children and
    ``branch_children`` their children (each sorted -X child, +X child, other: the frame's axes),
    ``levels`` per depth the free bones (parent has one child) and the branches whose children sit there."""

    parents: np.ndarray
    subtree: np.ndarray
    branches: tuple[int, ...]
    branch_children: tuple[np.ndarray, ...]
    levels: tuple[tuple[np.ndarray, tuple[int, ...]], ...]
    rest: np.ndarray  # (J, 3) the skeleton's unit rest directions
    depth: np.ndarray  # (J,) edges from the root

    @property
    def sizes(self) -> np.ndarray:
        """(J,) joints in each joint's subtree."""
        return self.subtree.sum(1)


@lru_cache(maxsize=8)
def _tree_of(sk: Skeleton) -> Tree:
    parents = np.asarray(sk.parents)
    J = len(parents)
    rest = sk.offsets_array
    kids = [[c for c in range(J) if parents[c] == j] for j in range(J)]
    subtree = np.eye(J)
    for c in range(J - 1, 0, -1):  # children after parents: accumulate bottom up
        subtree[parents[c]] += subtree[c]
    depth = np.zeros(J, dtype=int)
    for j in range(1, J):
        depth[j] = depth[parents[j]] + 1
    branches = tuple(j for j in range(J) if len(kids[j]) > 1)
    children = []
    for b in branches:
        neg = [c for c in kids[b] if rest[c][0] < 0]
        pos = [c for c in kids[b] if rest[c][0] > 0]
        other = [c for c in kids[b] if rest[c][0] == 0]
        if len(neg) != 1 or len(pos) != 1 or len(other) != 1:
            raise SMFError(f"cannot orient branching joint {sk.joint_names[b]}")
        children.append(np.array([neg[0], pos[0], other[0]]))
    levels = []
    for d in range(1, depth.max() + 1):
        free = np.array([c for c in range(J) if depth[c] == d and len(kids[parents[c]]) == 1], dtype=int)
        levels.append((free, tuple(i for i, b in enumerate(branches) if depth[b] == d - 1)))
    return Tree(parents, subtree, branches, tuple(children), tuple(levels), rest, depth)


def tree(skeleton: str | Skeleton = "humanml3d") -> Tree:
    """The (cached) :class:`Tree` of a skeleton."""
    return _tree_of(get_skeleton(skeleton))


def segment_mean(x: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Mean over each motion's frames: x (N, ...) with motions starting at ``starts`` (M,) -> (M, ...)."""
    counts = np.diff(np.append(starts, len(x)))
    return np.add.reduceat(x, starts, axis=0) / counts.reshape((-1,) + (1,) * (x.ndim - 1))


def per_frame(values: np.ndarray, starts: np.ndarray, n: int) -> np.ndarray:
    """Per-motion values (M, ...) repeated over each motion's frames -> (n, ...)."""
    return np.repeat(values, np.diff(np.append(starts, n)), axis=0)


_NEXT, _AFTER = np.array([1, 2, 0]), np.array([2, 0, 1])  # component k's two others, in cross-product order


def cross(a, b, axis: int = -1):
    """a x b along ``axis`` (of length 3), any array API library (numpy's np.cross is slow on small arrays):
    component k is a[k+1] b[k+2] - a[k+2] b[k+1], each side gathered at once."""
    xp = namespace(a, b)
    n, m = _as(a, _NEXT), _as(a, _AFTER)
    return xp.take(a, n, axis=axis) * xp.take(b, m, axis=axis) - xp.take(a, m, axis=axis) * xp.take(b, n, axis=axis)


def polar_rotation(k, fallback):
    """The rotation R (..., 3, 3) maximising tr(R^T k), k (..., 3, 3): the orthogonal polar factor of k, by scaled
    Newton steps X <- (g X + X^-T / g) / 2. Frames where det(k) <= 0 (no proper rotation is the polar
    factor: degenerate, never met on a body) keep ``fallback`` (..., 3, 3). Any array API library."""
    xp = namespace(k)
    x = k
    ok = None
    third = const(k, -1.0 / 3.0)
    for _ in range(POLAR_STEPS):
        # det(x) x^-T: its columns are those of x crossed in turn (b x c, c x a, a x b)
        cof = cross(xp.take(x, _as(x, _NEXT), axis=-1), xp.take(x, _as(x, _AFTER), axis=-1), axis=-2)
        det = xp.sum(x[..., :, :1] * cof[..., :, :1], axis=-2, keepdims=True)
        ok = det > 0 if ok is None else ok  # the sign of det(k), kept by every step
        safe = xp.where(ok, det, xp.ones_like(det))
        g = safe ** third
        x = 0.5 * (g * x + cof / (safe * g))
    return xp.where(ok, x, fallback)


def fit_bodies(targets: np.ndarray, starts: np.ndarray, lengths: np.ndarray, sweeps: int,
               skeleton: str | Skeleton = "humanml3d", begin: np.ndarray | None = None, like=None) -> np.ndarray:
    """Rigid joints (N, J, 3) metres fitted to ``targets`` (N, J, 3), the frames of motions starting at ``starts``
    (M,) stacked, with bone ``lengths`` (M, J) per motion: :func:`fit_joints` of the motions of each length, batched
    (a motion's result is the one it gets alone); computed by ``like``'s library on its device (a tensor on a GPU;
    None: numpy), numpy in and out."""
    ends = np.append(starts[1:], len(targets))
    out = np.empty_like(targets, dtype=np.float64)
    sizes = ends - starts
    for size in np.unique(sizes):
        which = np.flatnonzero(sizes == size)
        frames = (starts[which][:, None] + np.arange(size)).reshape(-1)
        shape = (len(which), size) + targets.shape[1:]
        fitted = fit_joints(on_like(targets[frames].reshape(shape), like), on_like(lengths[which], like), sweeps,
                            skeleton, None if begin is None else on_like(begin[frames].reshape(shape), like))
        out[frames] = to_numpy(fitted).reshape((-1,) + targets.shape[1:])
    return out


def _as(like, a: np.ndarray):
    """A constant of the tree (a float or index array) as an array of ``like``'s kind: numpy as it is, a tensor of
    ``like``'s precision (indices int64) and device."""
    if isinstance(like, np.ndarray):
        return a
    xp = namespace(like)
    return xp.asarray(a, device=device(like)) if a.dtype.kind == "i" else \
        xp.asarray(a, dtype=like.dtype, device=device(like))


def _joint_major(x):
    """(J, B, T, 3) of x (B, T, J, 3); numpy's laid out in that order (a view would make every step copy)."""
    out = namespace(x).permute_dims(x, (2, 0, 1, 3))
    return np.ascontiguousarray(out) if isinstance(out, np.ndarray) else out


def _unit(v):
    xp = namespace(v)
    return v / (xp.sqrt(xp.sum(v * v, axis=-1, keepdims=True)) + const(v, EPS))


def _spread(weights, x):
    """weights (K, J) @ x (J, ...) -> (K, ...): one matrix product over everything after the joints."""
    xp = namespace(x)
    return xp.reshape(weights @ xp.reshape(x, (x.shape[0], -1)), (weights.shape[0],) + tuple(x.shape[1:]))


def _rotate(r, v):
    """r (..., 3, 3) (columns: the axes) applied to v (..., 3), broadcast."""
    xp = namespace(v)
    return xp.sum(r * v[..., None, :], axis=-1)


def frame_of(left, right, centre, other, sign: float):
    """(..., 3, 3) a branching joint's orientation (columns x, y, z) from the positions (..., 3) of its -X child
    ``left``, its +X child ``right``, itself ``centre`` and its remaining child ``other``: X from left to right, Y
    towards ``other`` (``sign`` -1 where that child's rest direction points down), Z = X x Y."""
    xp = namespace(left)
    x = _unit(right - left)
    y = (other - centre) * sign
    y = _unit(y - xp.sum(y * x, axis=-1, keepdims=True) * x)
    return xp.stack([x, y, cross(x, y)], axis=-1)


def fit_joints(targets, lengths, sweeps: int, skeleton: str | Skeleton = "humanml3d", begin=None):
    """Rigid joints (B, T, J, 3) metres fitted to ``targets`` (B, T, J, 3) metres with bone ``lengths`` (B, J)
    metres per motion: the closed-form body of ``begin`` (default: the targets; a branch's children at their mean
    offset over the motion's frames, every other bone along its target), then ``sweeps`` exact block sweeps
    (module docstring). Array API, no loop over frames or motions: the graph ``rigid.onnx`` is this function."""
    xp = namespace(targets)
    t = tree(skeleton)
    tj = _joint_major(targets)  # (J, B, T, 3): each block one matrix product
    start = tj if begin is None else _joint_major(begin)
    length = xp.permute_dims(lengths, (1, 0))[:, :, None, None]  # (J, B, 1, 1)
    # 1. the closed form: each branch in the frame its children span, its children at their mean offsets
    frames, offsets = [], []
    for b, ch in zip(t.branches, t.branch_children):
        f = frame_of(start[ch[0]], start[ch[1]], start[b], start[ch[2]], float(np.sign(t.rest[ch[2], 1])))
        local = xp.sum((start[_as(tj, ch)] - start[b:b + 1])[..., :, None] * f, axis=-2)  # (3, B, T, 3)
        frames.append(f)
        offsets.append(_unit(xp.mean(local, axis=2, keepdims=True)) * length[_as(tj, ch)])  # (3, B, 1, 3)
    kids = np.concatenate(t.branch_children)
    single = np.array([j for j in range(1, len(t.parents)) if j not in kids])
    order = np.concatenate([[0], single, kids])
    bones = xp.concat([start[:1], length[_as(tj, single)] * _unit(start[_as(tj, single)]
                                                                        - start[_as(tj, t.parents[single])])]
                      + [_rotate(f[None], o) for f, o in zip(frames, offsets)], axis=0)
    x = _spread(_as(tj, t.subtree.T[:, order]), bones)  # each joint: the root plus the bones above it
    # 2. block sweeps, top down
    mean_of = t.subtree / t.sizes[:, None]  # (J, J): mean over a joint's subtree
    for _ in range(sweeps):
        x = x + xp.mean(tj - x, axis=0, keepdims=True)  # the root block
        for free, branch_ids in t.levels:
            for i in branch_ids:
                b, ch = t.branches[i], t.branch_children[i]
                c = _as(tj, ch)
                want = x[c] + _spread(_as(tj, mean_of[ch]), tj - x) - x[b:b + 1]  # (3, B, T, 3)
                n = _as(tj, t.sizes[ch].astype(np.float64))[:, None, None, None, None]
                k = xp.sum(n * want[..., :, None] * offsets[i][..., None, :], axis=0)  # (B, T, 3, 3)
                frames[i] = polar_rotation(k, frames[i])
                moved = x[b:b + 1] + _rotate(frames[i][None], offsets[i])
                x = x + _spread(_as(tj, t.subtree[ch].T), moved - x[c])
            if len(free):
                f, p = _as(tj, free), _as(tj, t.parents[free])
                want = x[f] + _spread(_as(tj, mean_of[free]), tj - x) - x[p]
                moved = x[p] + length[f] * _unit(want)
                x = x + _spread(_as(tj, t.subtree[free].T), moved - x[f])
    return xp.permute_dims(x, (1, 2, 0, 3))


def shortest_arc(a, b):
    """(..., 3, 3) rotation taking unit vectors a onto b (..., 3) by the shortest arc, from the normalised
    quaternion (1 + a.b, a x b) so it stays orthonormal near a half turn; opposite vectors get the half turn
    about an axis perpendicular to a. Any array API library."""
    xp = namespace(a, b)
    q = xp.concat([1.0 + xp.sum(a * b, axis=-1, keepdims=True), cross(a, b)], axis=-1)
    least = xp.argmin(xp.abs(a), axis=-1)[..., None]  # the basis vector least aligned with a
    e = xp.astype(least == _as(least, np.arange(3)), a.dtype)
    q = xp.where(q[..., :1] < const(q, 1e-6), xp.concat([xp.zeros_like(q[..., :1]), cross(a, e)], axis=-1), q)
    return quat_to_matrix(q / xp.sqrt(xp.sum(q * q, axis=-1, keepdims=True)))


def pose_joints(joints, lengths=None, skeleton: str | Skeleton = "humanml3d"):
    """Closed-form inverse kinematics of joints (B, T, J, 3) metres with bone ``lengths`` (B, J) metres -> rest
    offsets (B, J, 3) metres and local rotations (B, T, J, 3, 3): branching joints get the frame their children
    span (their children's offsets: the mean local position over the motion, at its length), every other bone lies
    along the skeleton's rest direction and turns by the shortest rotation from its parent's, leaves keep their
    parent's rotation. Exact for a rigid input with those lengths; without ``lengths``, each bone's mean length
    over the motion (and a branch's children at their mean local position). Array API, no loop over frames: the
    graph ``pose.onnx`` is this function."""
    xp = namespace(joints)
    t = tree(skeleton)
    J = len(t.parents)
    x = _joint_major(joints)  # (J, B, T, 3)
    bone = x - x[_as(x, t.parents)]
    size = xp.sqrt(xp.sum(bone * bone, axis=-1, keepdims=True))  # (J, B, T, 1)
    direction = bone / xp.maximum(size, const(bone, EPS))
    length = xp.mean(size, axis=2) if lengths is None else xp.permute_dims(lengths, (1, 0))[..., None]  # (J, B, 1)
    rows = [_as(x, t.rest[j])[None] * length[j] for j in range(J)]  # (B, 3) each
    glob = [None] * J
    for b, ch in zip(t.branches, t.branch_children):
        f = frame_of(x[ch[0]], x[ch[1]], x[b], x[ch[2]], float(np.sign(t.rest[ch[2], 1])))
        local = xp.sum((x[_as(x, ch)] - x[b:b + 1])[..., :, None] * f, axis=-2)  # (3, B, T, 3)
        mean = xp.mean(local, axis=2)  # (3, B, 3)
        offset = mean if lengths is None else _unit(mean) * length[_as(x, ch)]
        for k, c in enumerate(ch):
            rows[c] = offset[k]
        glob[b] = f
    rows[0] = xp.zeros_like(rows[0])
    eye = xp.zeros_like(x[0][..., None]) + _as(x, np.eye(3))  # (B, T, 3, 3)
    single = [j for j in range(J) if j not in t.branches]
    for d in range(int(t.depth.max()) + 1):  # joints by depth, each depth at once
        js = [j for j in single if t.depth[j] == d]
        for j in (j for j in js if not (t.parents == j).any()):  # a leaf keeps its parent's rotation
            glob[j] = eye if t.parents[j] < 0 else glob[t.parents[j]]
        js = [j for j in js if (t.parents == j).any()]
        if not js:
            continue
        kid = np.array([int(np.flatnonzero(t.parents == j)[0]) for j in js])
        parent_rot = xp.stack([eye if t.parents[j] < 0 else glob[t.parents[j]] for j in js])  # (n, B, T, 3, 3)
        rest_dir = xp.sum(parent_rot * _as(x, t.rest[kid])[:, None, None, None, :], axis=-1)
        turned = shortest_arc(rest_dir, direction[_as(x, kid)]) @ parent_rot
        for k, j in enumerate(js):
            glob[j] = turned[k]
    local = [glob[0]] + [xp.matrix_transpose(glob[t.parents[j]]) @ glob[j] for j in range(1, J)]
    return xp.stack(rows, axis=1), xp.stack(local, axis=2)


def pose_of_joints(joints: np.ndarray, starts: np.ndarray, skeleton: str | Skeleton = "humanml3d",
                   lengths: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pose_joints` of the motions of joints (N, J, 3) metres stacked, starting at frames ``starts`` (M,):
    rest offsets per motion (M, J, 3) metres and local rotations (N, J, 3, 3). ``lengths`` (M, J) per motion
    default to each bone's mean length over the motion."""
    lengths = None if lengths is None else np.asarray(lengths, dtype=np.float64)
    ends = np.append(starts[1:], len(joints))
    offsets = np.empty((len(starts),) + joints.shape[1:])
    local = np.empty(joints.shape + (3,))
    sizes = ends - starts
    for size in np.unique(sizes):
        which = np.flatnonzero(sizes == size)
        frames = (starts[which][:, None] + np.arange(size)).reshape(-1)
        o, r = pose_joints(joints[frames].reshape((len(which), size) + joints.shape[1:]),
                           None if lengths is None else lengths[which], skeleton)
        offsets[which] = o
        local[frames] = r.reshape((-1,) + local.shape[1:])
    return offsets, local


def positions_of_pose(offsets: np.ndarray, local: np.ndarray, root: np.ndarray,
                      skeleton: str | Skeleton = "humanml3d") -> np.ndarray:
    """Forward kinematics: rest offsets (J, 3) (or per frame (N, J, 3)) metres, local rotations (N, J, 3, 3),
    root (N, 3) metres -> joints (N, J, 3) metres (:func:`stablemofusion.motion.kinematics.forward_kinematics`
    on the skeleton's tree)."""
    return forward_kinematics(offsets, local, root, get_skeleton(skeleton).parents)
