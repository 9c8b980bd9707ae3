"""The rigid fit of many motions at once: closed form, block sweeps, pose, all vectorised over every frame.

Every function here works on the frames of all motions of a call stacked into one array (N, J, 3) and, where
a quantity is per motion (the rest offsets of a branching joint's children), on ``starts``: the first frame
of each motion in that stack (the motions are consecutive runs of frames). Apart from those per-motion
means, every frame is computed on its own, so a motion's result does not depend on what it is stacked with.

The fit minimises the summed squared distance of every joint to its target over one rigid skeleton (fixed
bone lengths) by exact block-coordinate sweeps, top down (:func:`sweep`):

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

from ..errors import SMFError
from .kinematics import forward_kinematics
from .rotation import quat_to_matrix
from .skeleton import Skeleton, get_skeleton

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


def _unit(v: np.ndarray) -> np.ndarray:
    return v / (np.linalg.norm(v, axis=-1, keepdims=True) + EPS)


def segment_mean(x: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Mean over each motion's frames: x (N, ...) with motions starting at ``starts`` (M,) -> (M, ...)."""
    counts = np.diff(np.append(starts, len(x)))
    return np.add.reduceat(x, starts, axis=0) / counts.reshape((-1,) + (1,) * (x.ndim - 1))


def per_frame(values: np.ndarray, starts: np.ndarray, n: int) -> np.ndarray:
    """Per-motion values (M, ...) repeated over each motion's frames -> (n, ...)."""
    return np.repeat(values, np.diff(np.append(starts, n)), axis=0)


def branch_frames(joints: np.ndarray, t: Tree) -> np.ndarray:
    """(N, B, 3, 3) orientation of every branching joint from joints (N, J, 3): X from its -X child to its
    +X child, Y towards its remaining child (up or down, by that child's rest direction), Z = X x Y."""
    ch = np.stack(t.branch_children)  # (B, 3)
    b = np.asarray(t.branches)
    x = _unit(joints[:, ch[:, 1]] - joints[:, ch[:, 0]])
    y = (joints[:, ch[:, 2]] - joints[:, b]) * np.sign(t.rest[ch[:, 2], 1])[:, None]
    y = _unit(y - (y * x).sum(-1, keepdims=True) * x)
    return np.stack([x, y, cross(x, y)], axis=-1)


def branch_offsets(joints: np.ndarray, frames: np.ndarray, starts: np.ndarray, t: Tree,
                   lengths: np.ndarray | None) -> np.ndarray:
    """(M, B, 3, 3) rest offsets (metres, in the branch's frame) of each branch's three children per motion:
    their mean local position over the motion's frames, scaled to ``lengths`` (M, J) when given."""
    ch = np.stack(t.branch_children)
    b = np.asarray(t.branches)
    rel = joints[:, ch] - joints[:, b][:, :, None]  # (N, B, 3, 3): child, xyz
    local = np.einsum("nbij,nbci->nbcj", frames, rel)
    mean = segment_mean(local, starts)
    if lengths is not None:
        mean = _unit(mean) * lengths[:, ch][..., None]
    return mean


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (..., 3) (numpy's np.cross is slow on small arrays)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def polar_rotation(k: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """The rotation R (N, 3, 3) maximising tr(R^T k), k (N, 3, 3): the orthogonal polar factor of k, by scaled
    Newton steps X <- (g X + X^-T / g) / 2. Frames where det(k) <= 0 (no proper rotation is the polar
    factor: degenerate, never met on a body) keep ``fallback`` (N, 3, 3)."""
    x = k
    ok = None
    for _ in range(POLAR_STEPS):
        a, b, c = x[..., :, 0], x[..., :, 1], x[..., :, 2]
        cof = np.stack([cross(b, c), cross(c, a), cross(a, b)], axis=-1)  # det(x) x^-T
        det = (a * cof[..., :, 0]).sum(-1)[..., None, None]
        ok = det > 0 if ok is None else ok  # the sign of det(k), kept by every step
        safe = np.where(ok, det, 1.0)
        g = safe ** (-1.0 / 3.0)
        x = 0.5 * (g * x + cof / (safe * g))
    return np.where(ok, x, fallback)


@dataclass
class Body:
    """The state of the fit, joint-major: joints (J, N, 3) metres, branch orientations (N, B, 3, 3), their
    children's rest offsets per frame (B, 3, N, 3; the children, then frames), bone lengths (J, N, 1) metres."""

    joints: np.ndarray
    frames: np.ndarray
    offsets: np.ndarray
    lengths: np.ndarray


def _rotate(r: np.ndarray, v: np.ndarray) -> np.ndarray:
    """r (N, 3, 3) applied to v (..., N, 3)."""
    return (r * v[..., None, :]).sum(-1)


def closed_form_body(targets: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
                     skeleton: str | Skeleton = "humanml3d") -> Body:
    """The closed-form rigid start for targets (N, J, 3) metres: the root on its target, each branch in the
    frame its children span (their offsets the motion's mean, at ``lengths``), every other bone along its
    target direction at its length (``lengths`` (M, J) per motion). Equals
    :func:`stablemofusion.motion.rigid.pose_from_joints`."""
    t = tree(skeleton)
    frames = branch_frames(targets, t)
    offsets = per_frame(branch_offsets(targets, frames, starts, t, lengths), starts, len(targets))
    offsets = np.ascontiguousarray(offsets.transpose(1, 2, 0, 3))  # (B, 3, N, 3)
    length = np.ascontiguousarray(per_frame(lengths, starts, len(targets)).T[..., None])  # (J, N, 1)
    tj = np.ascontiguousarray(targets.transpose(1, 0, 2))
    bones = length * _unit(tj - tj[t.parents])
    for i, ch in enumerate(t.branch_children):
        bones[ch] = _rotate(frames[:, i], offsets[i])
    bones[0] = tj[0]
    return Body(_spread(t.subtree.T, bones), frames, offsets, length)  # each joint: root plus the bones above it


def _spread(weights: np.ndarray, x: np.ndarray) -> np.ndarray:
    """weights (K, J) @ x (J, N, 3) -> (K, N, 3): one matrix product over all frames."""
    return (weights @ x.reshape(len(x), -1)).reshape((len(weights),) + x.shape[1:])


def sweep(body: Body, targets: np.ndarray, t: Tree) -> Body:
    """One top-down sweep of exact block updates (module docstring) towards joint-major targets (J, N, 3);
    returns the updated body."""
    x = body.joints + (targets - body.joints).mean(0)  # the root block
    frames = body.frames.copy()
    mean_of = t.subtree / t.sizes[:, None]  # (J, J): mean over a joint's subtree
    for free, branch_ids in t.levels:
        for i in branch_ids:
            b, ch = t.branches[i], t.branch_children[i]
            want = x[ch] + _spread(mean_of[ch], targets - x) - x[b]  # (3, N, 3): child, frame, xyz
            k = sum(n * want[c][:, :, None] * body.offsets[i, c][:, None, :] for c, n in enumerate(t.sizes[ch]))
            frames[:, i] = polar_rotation(k, frames[:, i])
            moved = x[b] + _rotate(frames[:, i], body.offsets[i])
            x = x + _spread(t.subtree[ch].T, moved - x[ch])
        if len(free):
            parent = t.parents[free]
            want = x[free] + _spread(mean_of[free], targets - x) - x[parent]
            moved = x[parent] + body.lengths[free] * _unit(want)
            x = x + _spread(t.subtree[free].T, moved - x[free])
    return Body(x, frames, body.offsets, body.lengths)


def fit_bodies(targets: np.ndarray, starts: np.ndarray, lengths: np.ndarray, sweeps: int,
               skeleton: str | Skeleton = "humanml3d", begin: np.ndarray | None = None) -> np.ndarray:
    """Rigid joints (N, J, 3) metres fitted to ``targets`` (N, J, 3) with bone ``lengths`` (M, J) per motion:
    the closed-form body of ``begin`` (default: the targets), then ``sweeps`` block sweeps towards the
    targets."""
    t = tree(skeleton)
    body = closed_form_body(targets if begin is None else begin, starts, lengths, skeleton)
    tj = np.ascontiguousarray(targets.transpose(1, 0, 2))
    for _ in range(sweeps):
        body = sweep(body, tj, t)
    return np.ascontiguousarray(body.joints.transpose(1, 0, 2))


def _shortest_arc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation taking unit vectors a onto b (..., 3) by the shortest arc, from the normalised
    quaternion (1 + a.b, a x b) so it stays orthonormal near a half turn; opposite vectors get the half turn
    about an axis perpendicular to a."""
    q = np.concatenate([1.0 + (a * b).sum(-1, keepdims=True), cross(a, b)], -1)
    flip = q[..., 0] < 1e-6
    if flip.any():
        a_f = a[flip]
        e = np.eye(3)[np.argmin(np.abs(a_f), axis=-1)]  # the basis vector least aligned with a
        q[flip] = np.concatenate([np.zeros(a_f.shape[:-1] + (1,)), cross(a_f, e)], -1)
    return quat_to_matrix(q / np.linalg.norm(q, axis=-1, keepdims=True))


def pose_of_joints(joints: np.ndarray, starts: np.ndarray, skeleton: str | Skeleton = "humanml3d",
                   lengths: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form inverse kinematics of joints (N, J, 3) metres -> rest offsets per motion (M, J, 3) metres
    and local rotations (N, J, 3, 3): branching joints get the frame their children span (offsets: the
    children's mean local position), every other bone lies along the skeleton's rest direction and turns by
    the shortest rotation from its parent's, leaves keep their parent's rotation. ``lengths`` (M, J) per
    motion default to each bone's mean length over the motion. Exact for a rigid input with those lengths."""
    t = tree(skeleton)
    N, J = joints.shape[:2]
    bone = joints - joints[:, t.parents]
    length = np.linalg.norm(bone, axis=-1)
    per_bone = segment_mean(length, starts) if lengths is None else np.asarray(lengths, dtype=np.float64)
    offsets = t.rest[None] * per_bone[..., None]
    frames = branch_frames(joints, t)
    branch_off = branch_offsets(joints, frames, starts, t, lengths)
    for i, ch in enumerate(t.branch_children):
        offsets[:, ch] = branch_off[:, i]
    offsets[:, 0] = 0.0
    glob = np.empty((N, J, 3, 3))
    glob[:, t.branches] = frames
    eye = np.broadcast_to(np.eye(3), (N, 3, 3))
    direction = bone / np.maximum(length, EPS)[..., None]
    single = [j for j in range(J) if j not in t.branches]
    # joints by depth: a one-child joint turns from its parent's rotation onto its bone; a leaf keeps it
    for d in range(t.depth.max() + 1):
        js = np.array([j for j in single if t.depth[j] == d], dtype=int)
        if not len(js):
            continue
        parent_rot = np.stack([eye if t.parents[j] < 0 else glob[:, t.parents[j]] for j in js], axis=1)
        kid = np.array([int(np.flatnonzero(t.parents == j)[0]) if (t.parents == j).any() else -1 for j in js])
        has = kid >= 0
        glob[:, js[~has]] = parent_rot[:, ~has]
        if has.any():
            c = kid[has]
            rest_dir = np.einsum("nkij,kj->nki", parent_rot[:, has], t.rest[c])
            glob[:, js[has]] = _shortest_arc(rest_dir, direction[:, c]) @ parent_rot[:, has]
    local = glob.copy()
    local[:, 1:] = np.swapaxes(glob[:, t.parents[1:]], -1, -2) @ glob[:, 1:]
    return offsets, local


def positions_of_pose(offsets: np.ndarray, local: np.ndarray, root: np.ndarray,
                      skeleton: str | Skeleton = "humanml3d") -> np.ndarray:
    """Forward kinematics: rest offsets (J, 3) (or per frame (N, J, 3)) metres, local rotations (N, J, 3, 3),
    root (N, 3) metres -> joints (N, J, 3) metres (:func:`stablemofusion.motion.kinematics.forward_kinematics`
    on the skeleton's tree)."""
    return forward_kinematics(offsets, local, root, get_skeleton(skeleton).parents)
