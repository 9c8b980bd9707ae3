"""Rigid bodies: one skeleton whose bones keep their lengths, posed by local rotations and a root path.

Every output of the pipeline (joints, features, video, BVH) comes from a :class:`RigidMotion`, so no bone
stretches and the BVH file (which can only hold a rigid skeleton) is the same motion as the joints.

Convention (BVH's): ``offsets[c]`` (J, 3) is joint c's rest position relative to its parent, in the parent's
frame; ``rotations[t, j]`` (T, J, 3, 3) is joint j's local rotation and turns the offsets of j's children.
Global rotations G_j = G_parent(j) @ R_j; positions p_0 = root, p_c = p_parent(c) + G_parent(c) @ offsets[c].
Joints are indexed in the skeleton's order, where every parent precedes its children.

Bone lengths are chosen once per motion (:data:`BONE_LENGTHS`): ``"dataset"`` takes the skeleton's target
lengths (HumanML3D's; every motion of a uniformed corpus has exactly these), ``"median"`` the median length of
each bone over the input's frames (also the fallback for skeletons without target lengths, e.g. KIT).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..core.errors import SMFError
from . import rigid_batch
from .features import bone_lengths, features_in_frames_of, joints_from_features, joints_from_rotations
from .kinematics import forward_kinematics  # also public here: the rigid body's forward kinematics
from .lbfgs import lbfgs
from .skeleton import Skeleton, get_skeleton

BONE_LENGTHS = ("dataset", "median")
CM = 100.0  # the optimisation works in centimetres, so squared errors are O(1)
COLLAPSED_M = 1e-6  # a frame whose every bone is shorter than this (m) has no pose to fit
BRANCH_SCALE = 15.0  # cm: about the lever of a branching joint's children (hips, spine, neck, collars)

# (X (T, J, 3) positions in cm, root_shift (T, 3) cm) -> (loss, dloss/dX, dloss/dshift); see :func:`optimise_pose`
PoseLoss = Callable[[np.ndarray, np.ndarray], tuple[float, np.ndarray, np.ndarray]]


@dataclass
class RigidMotion:
    """A rigid skeleton's motion: ``offsets`` (J, 3) metres, local ``rotations`` (T, J, 3, 3), ``root`` (T, 3)
    metres (see the module docstring for the convention); ``planted`` (T, 4) the feet the cleanup held."""

    offsets: np.ndarray
    rotations: np.ndarray
    root: np.ndarray
    skeleton: str = "humanml3d"
    # (T, 4) bool: the frames in which the footskate cleanup held each foot joint (left ankle, left toe, right ankle,
    # right toe); None where no cleanup ran
    planted: np.ndarray | None = field(default=None, repr=False, compare=False)
    # the joints of (offsets, rotations, root) when already known (the batched fit computes them for all
    # motions at once); used while those three are the same arrays (treat them as read-only)
    _known: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.root)

    @property
    def bone_lengths(self) -> np.ndarray:
        """(J,) length of the bone into each joint (0 for the root)."""
        return np.linalg.norm(self.offsets, axis=-1)

    def joints(self) -> np.ndarray:
        """(T, J, 3) joint positions in metres."""
        known = self._known
        if known is not None and known[0] is self.offsets and known[1] is self.rotations and known[2] is self.root:
            return known[3].copy()
        return rigid_batch.positions_of_pose(self.offsets, self.rotations, self.root, self.skeleton)

    def with_joints(self, joints: np.ndarray) -> "RigidMotion":
        """This motion, remembering ``joints`` (T, J, 3) as its forward kinematics (the caller computed them)."""
        self._known = (self.offsets, self.rotations, self.root, joints)
        return self

    def translated(self, shift: np.ndarray) -> "RigidMotion":
        """The same motion moved by ``shift`` (3,) metres."""
        shift = np.asarray(shift, dtype=np.float64)
        moved = replace(self, root=self.root + shift)
        known = self._known
        if known is not None and known[0] is self.offsets and known[1] is self.rotations and known[2] is self.root:
            moved.with_joints(known[3] + shift)
        return moved


def choose_bone_lengths(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d", mode: str = "dataset") -> np.ndarray:
    """(J,) bone lengths in metres for a rigid fit of joints (T, J, 3); ``mode`` one of :data:`BONE_LENGTHS`."""
    sk = get_skeleton(skeleton)
    if mode not in BONE_LENGTHS:
        raise SMFError(f"bone lengths must be one of {', '.join(BONE_LENGTHS)}, got {mode!r}")
    if mode == "dataset" and sk.bone_lengths is not None:
        return np.asarray(sk.bone_lengths, dtype=np.float64)
    return np.median(bone_lengths(np.asarray(joints, dtype=np.float64), sk), axis=0)


def pose_from_joints(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d",
                     lengths: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form inverse kinematics: joints (T, J, 3) -> (rest offsets (J, 3), local rotations (T, J, 3, 3)).

    Branching joints (pelvis, upper spine) get the frame spanned by their children and rest offsets that
    are the children's mean position in that frame; every other bone lies along the skeleton's rest
    direction, and turns by the shortest rotation from its parent-rotated rest direction, so the twist of
    each limb follows its parent. Leaf joints keep their parent's rotation. Bone ``lengths`` (J,) default
    to each bone's mean length. Exact for a rigid input with those lengths (:func:`rigid_batch.pose_of_joints`
    on one motion).
    """
    joints = np.asarray(joints, dtype=np.float64)
    per_motion = None if lengths is None else np.asarray(lengths, dtype=np.float64)[None]
    offsets, local = rigid_batch.pose_of_joints(joints, np.zeros(1, dtype=int), skeleton, per_motion)
    return offsets[0], local


def global_rotations(motion: RigidMotion) -> np.ndarray:
    """(T, J, 3, 3) global rotation of every joint: G_j = G_parent(j) @ R_j."""
    return forward_kinematics(motion.offsets, motion.rotations, motion.root, get_skeleton(motion.skeleton).parents,
                              global_rotations=True)[1]


def optimise_pose(motion: RigidMotion, loss: PoseLoss, iterations: int) -> RigidMotion:
    """Minimise ``loss`` over the pose and the root path of ``motion`` with L-BFGS (:func:`~stablemofusion.motion.
    lbfgs.lbfgs`); bone lengths never change. ``loss(X, shift)`` gets the posed joints X (T, J, 3) and the root's
    shift from ``motion.root`` (T, 3), both in centimetres, float64, and returns (value, dvalue/dX, dvalue/dshift).
    Returns the optimised motion (the input when ``iterations`` is 0).

    Parametrised for a well-conditioned problem: the root path, the global orientation of each branching
    joint (its children's offsets stay rigid) and the global direction of every other bone (its length
    fixed), so moving one bone moves its subtree without swinging it about a long lever. The rotations are
    then the closed-form pose of the result (:func:`pose_from_joints`: each bone's shortest turn from its
    parent, as the motion's own were), which reproduces its joints exactly."""
    if iterations <= 0:
        return motion
    sk = get_skeleton(motion.skeleton)
    body = _PoseParams(motion, sk)
    theta = lbfgs(body.objective(loss), body.theta0, iterations)
    x = body.positions(theta)[0] / CM
    offsets, rotations = pose_from_joints(x, sk, motion.bone_lengths)
    return RigidMotion(offsets, rotations, x[:, 0].copy(), motion.skeleton)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last dim (3) of same-shaped arrays (np.cross's axis handling costs more here)."""
    out = np.empty_like(a)
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _tree_sum(v: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(T, J, 3) -> (T, J, 3): out[:, k] = sum_j weights[j, k] v[:, j] (one matrix product for all frames)."""
    return np.tensordot(v, weights, axes=([1], [0])).transpose(0, 2, 1)


class _PoseParams:
    """The parametrisation of :func:`optimise_pose` as one flat vector: bone vectors of the free bones in cm
    (T, F, 3), scaled 6D orientations of the branching joints (T, B, 6), the root's shift in cm (T, 3); the
    joints it poses and the chain rule back from the joints' gradient."""

    def __init__(self, motion: RigidMotion, sk: Skeleton):
        parents = np.asarray(sk.parents)
        J = sk.num_joints
        kids = np.bincount(parents[1:], minlength=J)
        self.parents, self.J = parents, J
        self.branch = [j for j in range(J) if kids[j] > 1]
        self.free = [c for c in range(1, J) if kids[parents[c]] == 1]  # bones free to turn: parent has one child
        self.under_branch = [c for c in range(1, J) if kids[parents[c]] > 1]
        b_index = {j: i for i, j in enumerate(self.branch)}
        self.branch_of = np.asarray([b_index[parents[c]] for c in self.under_branch])
        x0 = motion.joints()
        glob = global_rotations(motion)[:, self.branch]
        self.off = motion.offsets * CM
        self.length = motion.bone_lengths * CM
        self.root0 = motion.root * CM
        T = len(x0)
        u0 = (x0[:, self.free] - x0[:, parents[self.free]]) * CM
        g0 = np.concatenate([glob[..., :, 0], glob[..., :, 1]], -1) * BRANCH_SCALE
        self.shapes = [u0.shape, g0.shape, (T, 3)]
        self.theta0 = np.concatenate([u0.ravel(), g0.ravel(), np.zeros(T * 3)])
        sub = np.eye(J)  # subtree[j, k] = 1 where k is j or below it
        for c in range(J - 1, 0, -1):
            sub[parents[c]] += sub[c]
        self.subtree = np.minimum(sub, 1.0)
        # (C, B, 3): each bone under a branching joint's offset, in that joint's column
        self.off_by_branch = np.zeros((len(self.under_branch), len(self.branch), 3))
        self.off_by_branch[np.arange(len(self.under_branch)), self.branch_of] = self.off[self.under_branch]

    def split(self, theta: np.ndarray) -> list[np.ndarray]:
        out, a = [], 0
        for shape in self.shapes:
            n = int(np.prod(shape))
            out.append(theta[a:a + n].reshape(shape))
            a += n
        return out

    def positions(self, theta: np.ndarray):
        """Joints (T, J, 3) cm of ``theta``, and what the chain rule needs."""
        u, g6, shift = self.split(theta)
        a, b = g6[..., :3] / BRANCH_SCALE, g6[..., 3:] / BRANCH_SCALE
        na = np.linalg.norm(a, axis=-1, keepdims=True)
        x = a / na
        w = _cross(x, b)
        nw = np.linalg.norm(w, axis=-1, keepdims=True)
        z = w / nw
        y = _cross(z, x)
        rot = np.stack([x, y, z], -1)  # (T, B, 3, 3) columns x, y, z
        nu = np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-6)
        bones = np.zeros((len(u), self.J, 3))
        bones[:, self.free] = self.length[self.free, None] * u / nu
        bones[:, self.under_branch] = np.einsum("tcij,cj->tci", rot[:, self.branch_of], self.off[self.under_branch])
        X = _tree_sum(bones, self.subtree) + (self.root0 + shift)[:, None]  # each joint: its root and bones above
        return X, (u, nu, a, na, b, x, y, z, w, nw, shift)

    def objective(self, loss: PoseLoss):
        def f(theta: np.ndarray) -> tuple[float, np.ndarray]:
            X, (u, nu, a, na, b, x, y, z, w, nw, shift) = self.positions(theta)
            value, gX, gshift = loss(X, shift)
            g_bone = _tree_sum(gX, self.subtree.T)  # (T, J, 3): a bone moves its whole subtree
            # free bones: bone = length * u / |u|
            gb = g_bone[:, self.free]
            n = u / nu
            g_u = self.length[self.free, None] / nu * (gb - n * np.sum(n * gb, -1, keepdims=True))
            # branching joints: bone_c = R_b off_c, R = Gram-Schmidt of (a, b)
            g_rot = np.tensordot(g_bone[:, self.under_branch], self.off_by_branch, axes=([1], [0]))  # (T, 3, B, 3)
            g_rot = g_rot.transpose(0, 2, 1, 3)
            gx, gy, gz = g_rot[..., 0], g_rot[..., 1], g_rot[..., 2]
            gz = gz + _cross(x, gy)  # y = z x x
            gx = gx + _cross(gy, z)
            gw = (gz - z * np.sum(z * gz, -1, keepdims=True)) / nw  # z = w / |w|
            gx = gx + _cross(b, gw)  # w = x x b
            g_b = _cross(gw, x)
            g_a = (gx - x * np.sum(x * gx, -1, keepdims=True)) / na  # x = a / |a|
            g_g6 = np.concatenate([g_a, g_b], -1) / BRANCH_SCALE
            g_shift = gshift + gX.sum(1)
            return float(value), np.concatenate([g_u.ravel(), g_g6.ravel(), g_shift.ravel()])

        return f


FIT_STARTS = ("rotations", "positions")
FIT_METHODS = ("sweeps", "lbfgs")  # exact block sweeps, batched over all motions; or L-BFGS per motion
DEFAULT_ITERATIONS = {"sweeps": 4, "lbfgs": 20}
FEATURE_ROTATIONS = ("ik", "keep")


@dataclass(frozen=True)
class RigidFitConfig:
    """How the pipeline's rigid final stage fits a rigid body to a model's features (:func:`rigid_from_features`)
    and writes it back as features (:func:`rigid_to_features`)."""

    bone_lengths: str = "dataset"  # one of BONE_LENGTHS
    iterations: int | None = None  # sweeps or L-BFGS iterations (0: the closed-form start only; None: the
    # method's default, DEFAULT_ITERATIONS)
    start: str = "positions"  # closed-form start from the positions, or from the joints the rotation channels describe
    rotations: str = "keep"  # feature rotation channels: the model's own ("keep"), or "ik" of the rigid joints
    method: str = "sweeps"  # one of FIT_METHODS

    def __post_init__(self):
        if self.method not in FIT_METHODS:
            raise SMFError(f"method must be one of {', '.join(FIT_METHODS)}, got {self.method!r}")
        if self.iterations is None:
            object.__setattr__(self, "iterations", DEFAULT_ITERATIONS[self.method])
        if self.bone_lengths not in BONE_LENGTHS:
            raise SMFError(f"bone lengths must be one of {', '.join(BONE_LENGTHS)}, got {self.bone_lengths!r}")
        if self.start not in FIT_STARTS:
            raise SMFError(f"start must be one of {', '.join(FIT_STARTS)}, got {self.start!r}")
        if self.rotations not in FEATURE_ROTATIONS:
            raise SMFError(f"rotations must be one of {', '.join(FEATURE_ROTATIONS)}, got {self.rotations!r}")


DEFAULT_FIT = RigidFitConfig()


def _checked_targets(targets: np.ndarray, sk: Skeleton) -> np.ndarray:
    x = np.asarray(targets, dtype=np.float64)
    if x.ndim != 3 or x.shape[1:] != (sk.num_joints, 3) or len(x) < 1:
        raise SMFError(f"expected joints of shape (T, {sk.num_joints}, 3), got {tuple(x.shape)}")
    if not np.isfinite(x).all():
        raise SMFError("joints contain NaN or inf")
    collapsed = bone_lengths(x, sk)[:, 1:].max(-1) < COLLAPSED_M
    if collapsed.any():
        raise SMFError(f"the joints of {int(collapsed.sum())} frames (first: {int(np.argmax(collapsed))}) all sit on one "
                       "point: no skeleton can be fitted to them")
    return x


def fit_rigid_many(targets: list[np.ndarray], skeleton: str | Skeleton = "humanml3d",
                   config: RigidFitConfig = DEFAULT_FIT, *, starts: list[np.ndarray | None] | None = None,
                   like=None) -> list[RigidMotion]:
    """Fit one rigid skeleton to each motion's joint positions ``targets[i]`` (T_i, J, 3) metres, all motions at
    once: bone lengths by ``config.bone_lengths``; the closed-form pose of ``starts[i]`` (T_i, J, 3) (default:
    the targets themselves), then ``config.iterations`` block sweeps (``method="sweeps"``, vectorised over
    every frame of every motion; :mod:`stablemofusion.motion.rigid_batch`) or L-BFGS steps per motion
    (``"lbfgs"``) towards the targets. A motion's result does not depend on the others. ``like``: the sweeps run
    on its library and device (:func:`~stablemofusion.motion.rigid_batch.fit_bodies`)."""
    sk = get_skeleton(skeleton)
    xs = [_checked_targets(x, sk) for x in targets]
    begins = [None] * len(xs) if starts is None else list(starts)
    lengths = np.stack([choose_bone_lengths(x, sk, config.bone_lengths) for x in xs])  # (M, J)
    if config.method == "lbfgs":
        out = []
        for x, begin, length in zip(xs, begins, lengths):
            offsets, rotations = pose_from_joints(x if begin is None else begin, sk, length)
            out.append(optimise_pose(RigidMotion(offsets, rotations, x[:, 0].copy(), sk.name),
                                     _squared_distance(x * CM), config.iterations))
        return out
    fitted, starts_at = _swept(xs, begins, lengths, sk, config, like)
    offsets, rotations = rigid_batch.pose_of_joints(fitted, starts_at, sk, lengths)
    root = fitted[:, 0].copy()
    joints = rigid_batch.positions_of_pose(rigid_batch.per_frame(offsets, starts_at, len(fitted)), rotations, root, sk)
    ends = np.append(starts_at[1:], len(fitted))
    return [RigidMotion(offsets[i], rotations[a:b], root[a:b], sk.name).with_joints(joints[a:b])
            for i, (a, b) in enumerate(zip(starts_at, ends))]


def _swept(xs: list[np.ndarray], begins: list, lengths: np.ndarray, sk: Skeleton, config: RigidFitConfig,
           like=None) -> tuple[np.ndarray, np.ndarray]:
    """The block-sweep fit of every frame of the motions ``xs`` at once: rigid joints (N, J, 3) of all of them
    stacked, and each motion's first frame in that stack."""
    starts_at = np.cumsum([0] + [len(x) for x in xs[:-1]])
    stacked = np.concatenate(xs)
    begin = None if all(b is None for b in begins) else \
        np.concatenate([x if b is None else np.asarray(b, dtype=np.float64) for x, b in zip(xs, begins)])
    return rigid_batch.fit_bodies(stacked, starts_at, lengths, config.iterations, sk, begin, like), starts_at


def rigid_joints_of_features(features: list[np.ndarray], skeleton: str | Skeleton = "humanml3d",
                             config: RigidFitConfig = DEFAULT_FIT, like=None) -> tuple[list[np.ndarray], np.ndarray]:
    """The joints (T_i, J, 3) metres of :func:`rigid_from_features_many`'s bodies and their bone lengths (M, J),
    without the pose (rotations) of each body: for a stage that moves the joints before posing them (the
    footskate cleanup). Block sweeps only (on ``like``'s library and device)."""
    if config.method != "sweeps":
        bodies = rigid_from_features_many(features, skeleton, config)
        return [b.joints() for b in bodies], np.stack([b.bone_lengths for b in bodies])
    sk = get_skeleton(skeleton)
    targets, starts = _feature_targets(features, sk, config)
    xs = [_checked_targets(x, sk) for x in targets]
    lengths = np.stack([choose_bone_lengths(x, sk, config.bone_lengths) for x in xs])
    fitted, starts_at = _swept(xs, [None] * len(xs) if starts is None else starts, lengths, sk, config, like)
    return np.split(fitted, starts_at[1:]), lengths


def _squared_distance(target: np.ndarray) -> PoseLoss:
    """The mean over frames of the summed squared distance of every joint to ``target`` (T, J, 3) cm."""

    def loss(X: np.ndarray, shift: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        d = X - target
        return float((d ** 2).sum() / len(X)), 2 * d / len(X), np.zeros_like(shift)

    return loss


def fit_rigid(targets: np.ndarray, skeleton: str | Skeleton = "humanml3d", config: RigidFitConfig = DEFAULT_FIT, *,
              start: np.ndarray | None = None) -> RigidMotion:
    """Fit a rigid skeleton to joint positions ``targets`` (T, J, 3) metres (:func:`fit_rigid_many` of one)."""
    return fit_rigid_many([targets], skeleton, config, starts=[start])[0]


def rigid_from_features_many(features: list[np.ndarray], skeleton: str | Skeleton = "humanml3d",
                             config: RigidFitConfig = DEFAULT_FIT, like=None) -> list[RigidMotion]:
    """The rigid bodies that a model's features (T_i, D) describe, fitted together: their joint positions are
    the targets, and the joints their rotation channels describe (with the chosen bone lengths) the start
    (``config.start``); the sweeps on ``like``'s library and device (None: numpy)."""
    sk = get_skeleton(skeleton)
    targets, starts = _feature_targets(features, sk, config)
    return fit_rigid_many(targets, sk, config, starts=starts, like=like)


def _feature_targets(features: list[np.ndarray], sk: Skeleton, config: RigidFitConfig) -> tuple[list, list | None]:
    """The fit's targets (the features' joint positions) and starts (the joints their rotation channels describe,
    where ``config.start`` says so) of features (T_i, D)."""
    fs = [np.asarray(f, dtype=np.float64) for f in features]
    targets = [joints_from_features(f, sk) for f in fs]
    starts = None
    if config.start == "rotations":
        starts = [joints_from_rotations(f, sk, choose_bone_lengths(x, sk, config.bone_lengths))
                  for f, x in zip(fs, targets)]
    return targets, starts


def rigid_from_features(features: np.ndarray, skeleton: str | Skeleton = "humanml3d",
                        config: RigidFitConfig = DEFAULT_FIT) -> RigidMotion:
    """The rigid body that a model's features (T, D) describe (:func:`rigid_from_features_many` of one)."""
    return rigid_from_features_many([features], skeleton, config)[0]


def rigid_to_features(motion: RigidMotion, reference: np.ndarray,
                      config: RigidFitConfig = DEFAULT_FIT) -> tuple[RigidMotion, np.ndarray]:
    """Features (T, D) of ``motion`` in the body frames of the ``reference`` features it was fitted to (see
    :func:`stablemofusion.motion.features.features_in_frames_of`), and the motion moved so that its first root
    sits at the XZ origin, where the features' decoding starts: the features decode to its joints exactly."""
    moved = motion.translated(-motion.root[0] * np.array([1.0, 0.0, 1.0]))
    return moved, features_in_frames_of(moved.joints(), reference, motion.skeleton, rotations=config.rotations)


def bone_length_deviation(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d") -> dict[str, float]:
    """How far a motion's bones stray from their own median length, joints (T, J, 3) metres:
    ``bone_std`` the mean over bones of each bone's length std (m), ``bone_worst`` the largest deviation of
    any bone in any frame from its median (m)."""
    sk = get_skeleton(skeleton)
    lengths = bone_lengths(np.asarray(joints, dtype=np.float64), sk)[:, 1:]
    return {"bone_std": float(lengths.std(0).mean()),
            "bone_worst": float(np.abs(lengths - np.median(lengths, 0)).max())}
