"""The HumanML3D motion representation: joints <-> 263-dim features (251 for KIT-ML).

Feature layout per frame (J joints): root yaw velocity (1, half-angle radians per frame), root XZ
velocity in the body frame (2, units per frame), root height (1), root-relative joint positions in the
body frame (3*(J-1)), continuous 6D joint rotations from inverse kinematics (6*(J-1)), joint velocities in
the body frame (3*J), foot contacts (4: left ankle, left toe, right ankle, right toe).
The algorithm and its quirks follow the official HumanML3D processing so features agree with the dataset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import MotionFormatError
from . import timeseries as ts
from .arrays import device, float64_numpy, namespace
from .kinematics import forward_kinematics
from .rotation import cont6d_to_matrix, qbetween, qinv, qmul, qrot, quat_to_cont6d, quat_to_matrix, yaw_quat
from .skeleton import Skeleton, get_skeleton

_Y = np.array([0.0, 1.0, 0.0])
_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class FeatureSlices:
    """Index ranges of each group inside a feature vector."""

    root_yaw_velocity: slice
    root_xz_velocity: slice
    root_height: slice
    positions: slice
    rotations: slice
    velocities: slice
    contacts: slice

    def items(self) -> list[tuple[str, slice]]:
        return list(self.__dict__.items())


def feature_slices(skeleton: str | Skeleton = "humanml3d") -> FeatureSlices:
    """Where each group lives in a feature vector of ``skeleton``."""
    j = get_skeleton(skeleton).num_joints
    p = 4 + 3 * (j - 1)
    r = p + 6 * (j - 1)
    v = r + 3 * j
    return FeatureSlices(slice(0, 1), slice(1, 3), slice(3, 4), slice(4, p), slice(p, r), slice(r, v), slice(v, v + 4))


def _check_joints(joints: np.ndarray, sk: Skeleton, min_frames: int = 1) -> np.ndarray:
    arr = np.asarray(joints)
    if arr.ndim != 3 or arr.shape[1:] != (sk.num_joints, 3):
        raise MotionFormatError(f"expected joints of shape (T, {sk.num_joints}, 3), got {tuple(arr.shape)}")
    if arr.shape[0] < min_frames:
        raise MotionFormatError(f"need at least {min_frames} frames, got {arr.shape[0]}")
    if not np.issubdtype(arr.dtype, np.number) or not np.isfinite(arr).all():
        raise MotionFormatError("joints contain NaN or inf")
    return arr.astype(np.float64)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def bone_lengths(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d") -> np.ndarray:
    """(..., J, 3) joints -> (..., J) length of the bone into each joint (0 for the root)."""
    sk = get_skeleton(skeleton)
    parents = np.array(sk.parents)
    parents[0] = 0
    return np.linalg.norm(joints - joints[..., parents, :], axis=-1)


def uniform_skeleton(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d",
                     target_lengths: np.ndarray | None = None) -> np.ndarray:
    """Give every bone the target length, keeping bone directions; scale the root path by leg length.

    joints (T, J, 3). The leg scale compares thigh + shin of frame 0 with the target, as HumanML3D does.
    """
    sk = get_skeleton(skeleton)
    tgt = np.asarray(sk.bone_lengths if target_lengths is None else target_lengths, dtype=np.float64)
    src = bone_lengths(joints[0], sk)
    k, a = sk.leg_joints
    scale = (tgt[k] + tgt[a]) / (src[k] + src[a])
    parents = np.asarray(sk.parents)
    bones = np.zeros(joints.shape[:-1] + (3,), dtype=np.result_type(joints, tgt))  # the root's unused
    bones[:, 1:] = _unit(joints[:, 1:] - joints[:, parents[1:]]) * tgt[1:, None]
    out = forward_kinematics(bones, None, joints[:, 0] * scale, sk.parents)  # each bone added to its parent
    return out.astype(joints.dtype, copy=False)


def _across(joints: np.ndarray, sk: Skeleton, official_ik: bool) -> np.ndarray:
    """Right-pointing body axis from hips and shoulders, (T, 3)."""
    r_hip, l_hip, r_sh, l_sh = sk.face_joints
    if official_ik:
        # HumanML3D's inverse kinematics unpacks the face joints in another order: the hip term points
        # left and the (wider) shoulder term right. Reproduced on purpose so rotations match the dataset.
        return (joints[:, l_hip] - joints[:, r_hip]) + (joints[:, r_sh] - joints[:, l_sh])
    return (joints[:, r_hip] - joints[:, l_hip]) + (joints[:, r_sh] - joints[:, l_sh])


def gaussian_smooth(x: np.ndarray, sigma: float, truncate: float = 4.0) -> np.ndarray:
    """Gaussian smoothing along axis 0 of ``x`` (T, ...) with standard deviation ``sigma`` frames, the edges
    extended by their nearest value; the kernel reaches ``truncate`` sigmas (scipy.ndimage.gaussian_filter1d with
    mode="nearest", in numpy): :func:`~stablemofusion.motion.timeseries.window` of one series."""
    x = np.asarray(x, dtype=np.float64)
    out = ts.window(x.reshape(1, len(x), -1), ts.gaussian(sigma, truncate), edge=True)
    return out.reshape(x.shape)


def facing_quat(joints: np.ndarray, sk: Skeleton, *, official_ik: bool = False, smooth: float = 0.0) -> np.ndarray:
    """(T, J, 3) -> (T, 4) yaw quaternion that turns each frame's facing direction to +Z."""
    forward = np.cross(_Y, _unit(_across(joints, sk, official_ik)))
    if smooth > 0:
        forward = gaussian_smooth(forward, smooth)
    forward = _unit(forward)
    return qbetween(forward, np.broadcast_to(_Z, forward.shape))


def inverse_kinematics(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d", *,
                       smooth_forward: bool = True, root: np.ndarray | None = None) -> np.ndarray:
    """HumanML3D inverse kinematics: (T, J, 3) -> (T, J, 4) quaternions.

    Index 0 holds the root yaw (identity on frame 0, as in the official code; or the given ``root`` (T, 4)
    body-frame quaternions); index c holds the rotation of the bone parent(c) -> c relative to the
    accumulated rotation along its chain, taking the bone's rest direction ``raw_offsets[c]`` onto its
    actual direction by the shortest arc.
    """
    sk = get_skeleton(skeleton)
    if root is None:
        root = facing_quat(joints, sk, official_ik=True, smooth=20.0 if smooth_forward else 0.0)
        root[0] = (1.0, 0.0, 0.0, 0.0)
    # Every bone p -> c of a chain at once: its swing from the rest direction, relative to the swing of the
    # bone before it in the chain (the root rotation for a chain's first bone).
    bones = [(p, c, i == 0) for chain in sk.chains for i, (p, c) in enumerate(zip(chain[:-1], chain[1:]))]
    parent, child, first = (np.array(v) for v in zip(*bones))
    swings = np.zeros(joints.shape[:-1] + (4,))
    swings[:, child] = qbetween(sk.offsets_array[child], _unit(joints[:, child] - joints[:, parent]))
    acc = np.where(first[:, None], root[:, None], swings[:, parent])
    quats = np.zeros(joints.shape[:-1] + (4,))
    quats[:, 0] = root
    quats[:, child] = qmul(qinv(acc), swings[:, child])
    return quats


def canonicalize(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d", *, uniform: bool = True) -> np.ndarray:
    """Put a motion in HumanML3D's canonical frame: uniform skeleton, feet on the floor (min Y = 0),
    first root at the XZ origin, first frame facing +Z. (T, J, 3) -> (T, J, 3)."""
    sk = get_skeleton(skeleton)
    pos = _check_joints(joints, sk)
    if uniform and sk.bone_lengths is not None:
        pos = uniform_skeleton(pos, sk)
    pos = pos.copy()
    pos[..., 1] -= pos[..., 1].min()
    pos -= pos[0, 0] * np.array([1.0, 0.0, 1.0])
    q0 = facing_quat(pos[:1], sk)[0]
    return qrot(np.broadcast_to(q0, pos.shape[:-1] + (4,)), pos)


def foot_contacts(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d", threshold: float | None = None) -> np.ndarray:
    """(T, J, 3) -> (T-1, 4) contacts (left ankle, left toe, right ankle, right toe): 1 where the joint's
    squared displacement to the next frame is below ``threshold`` (units^2; HumanML3D uses 0.002 m^2)."""
    sk = get_skeleton(skeleton)
    thr = sk.foot_velocity_threshold if threshold is None else threshold
    feet = list(sk.foot_left) + list(sk.foot_right)
    disp = ((joints[1:, feet] - joints[:-1, feet]) ** 2).sum(-1)
    return (disp < thr).astype(np.float64)


FIRST_FRAME = ("official", "consistent")


def features_from_joints(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d", *, uniform: bool = True,
                         feet_threshold: float | None = None, first_frame: str = "official") -> np.ndarray:
    """Joint positions (T, J, 3) in metres, Y up -> features (T-1, 263) for HumanML3D (251 for KIT).

    Canonicalises first (see :func:`canonicalize`); ``uniform`` rescales bones to the target skeleton
    (HumanML3D only: KIT has no known target, so its bone lengths are kept).

    ``first_frame``: "official" reproduces HumanML3D, whose frame 0 faces +Z by one facing estimate while its
    root rotation is set to the identity and every later frame uses the inverse kinematics' own (smoothed)
    facing: frame 0 then sits in another body frame than frame 1, and the first yaw velocity holds the jump
    between the two (2.6 degrees median, 14 degrees 95th percentile on our corpus). "consistent" turns the
    motion so that the inverse kinematics' facing of frame 0 is +Z: every frame, the first too, is in the same
    kind of body frame and the first yaw velocity is an ordinary one. Both decode the same way. (A model trained
    briefly on "consistent" data did not turn its first frame less: docs/rigid.md.)
    """
    sk = get_skeleton(skeleton)
    if first_frame not in FIRST_FRAME:
        raise MotionFormatError(f"first_frame must be one of {', '.join(FIRST_FRAME)}, got {first_frame!r}")
    pos = canonicalize(_check_joints(joints, sk, min_frames=2), sk, uniform=uniform)
    if first_frame == "consistent":
        q0 = facing_quat(pos, sk, official_ik=True, smooth=20.0)[0]
        pos = qrot(np.broadcast_to(q0, pos.shape[:-1] + (4,)), pos)
    contacts = foot_contacts(pos, sk, feet_threshold)
    quats = inverse_kinematics(pos, sk, smooth_forward=True)
    r_rot = quats[:, 0]
    root_vel = qrot(r_rot[1:], pos[1:, 0] - pos[:-1, 0])
    # The yaw step as a quaternion with w >= 0: the IK's facing quaternions change sign when the facing passes
    # 180 degrees, and arcsin of the raw y component then gives the step with the wrong sign (HumanML3D's
    # encoder has that flaw; the decoded root path turns the wrong way from that frame on).
    step_q = qmul(r_rot[1:], qinv(r_rot[:-1]))
    step_q = np.where(step_q[:, :1] < 0, -step_q, step_q)
    yaw_vel = np.arcsin(np.clip(step_q[:, 2:3], -1.0, 1.0))
    local = pos.copy()
    local[..., 0] -= pos[:, :1, 0]
    local[..., 2] -= pos[:, :1, 2]
    local = qrot(np.broadcast_to(r_rot[:, None], local.shape[:-1] + (4,)), local)
    vel = qrot(np.broadcast_to(r_rot[:-1, None], pos[1:].shape[:-1] + (4,)), pos[1:] - pos[:-1])
    T = len(pos) - 1
    return np.concatenate([
        yaw_vel, root_vel[:, [0, 2]], local[:-1, 0, 1:2],
        local[:-1, 1:].reshape(T, -1),
        quat_to_cont6d(quats[:-1, 1:]).reshape(T, -1),
        vel.reshape(T, -1),
        contacts,
    ], axis=-1)


def _check_features(features, sk: Skeleton, values: bool = True) -> None:
    shape = tuple(features.shape)
    if len(shape) < 2 or shape[-1] != sk.feature_dim:
        raise MotionFormatError(f"expected features of shape (..., T, {sk.feature_dim}), got {shape}")
    if not values:
        return
    # A finite sum means every value is finite (NaN and inf propagate); only a non-finite sum (or an overflow)
    # needs the element-wise look. Written with operators so that it reads numpy arrays and tensors alike.
    if not bool(abs(features.sum()) < float("inf")) and not bool((abs(features) < float("inf")).all()):
        raise MotionFormatError("features contain NaN or inf")


@float64_numpy
def root_from_features(features):
    """Integrate root yaw and position: (..., T, D) -> yaw quaternions (..., T, 4), root (..., T, 3) in metres
    (numpy in: float64 numpy out)."""
    xp = namespace(features)
    yaw_vel = features[..., 0]
    zero = xp.zeros_like(yaw_vel[..., :1])
    angle = xp.cumulative_sum(xp.concat([zero, yaw_vel[..., :-1]], axis=-1), axis=-1)
    # The stored value is the yaw half-angle, so the quaternion uses it directly: (cos a, 0, sin a, 0).
    quat = yaw_quat(2.0 * angle)
    z = xp.zeros_like(features[..., :1, 0])
    step = xp.stack([xp.concat([z, features[..., :-1, 1]], axis=-1), xp.zeros_like(yaw_vel),
                     xp.concat([z, features[..., :-1, 2]], axis=-1)], axis=-1)
    root = xp.cumulative_sum(qrot(qinv(quat), step), axis=-2)
    root = xp.stack([root[..., 0], features[..., 3], root[..., 2]], axis=-1)
    return quat, root


@float64_numpy
def joints_from_features(features, skeleton: str | Skeleton = "humanml3d", *, finite_check: bool = True):
    """Features (..., T, D) -> joint positions (..., T, J, 3) in metres, through the root-relative positions.

    Accepts numpy arrays (returns numpy, float64 math) or torch tensors (returns torch, same dtype/device,
    differentiable). ``finite_check`` False skips the look at every value (a graph being traced cannot branch on
    values; its caller checks).
    """
    sk = get_skeleton(skeleton)
    x = features
    _check_features(x, sk, finite_check)
    quat, root = root_from_features(x)
    J = sk.num_joints
    local = x[..., 4:4 + 3 * (J - 1)].reshape(x.shape[:-1] + (J - 1, 3))
    xp = namespace(x)
    world = qrot(xp.broadcast_to(qinv(quat)[..., None, :], tuple(local.shape[:-1]) + (4,)), local)
    world = xp.concat([world[..., :1] + root[..., None, :1], world[..., 1:2], world[..., 2:] + root[..., None, 2:]],
                      axis=-1)
    return xp.concat([root[..., None, :], world], axis=-2)


@float64_numpy
def joints_from_rotations(features: np.ndarray, skeleton: str | Skeleton = "humanml3d",
                          lengths: np.ndarray | None = None) -> np.ndarray:
    """Features (T, D) -> joints (T, J, 3) through the rotation channels instead of the positions: the root
    path, then each bone of ``lengths`` (J,) metres (default: the skeleton's target lengths) along the
    direction its chain of 6D rotations gives (HumanML3D's forward kinematics). Exact for real features.
    numpy in: float64 math, numpy out; torch in: torch out."""
    sk = get_skeleton(skeleton)
    x = features
    _check_features(x, sk)
    if lengths is None:
        if sk.bone_lengths is None:
            raise MotionFormatError(f"the {sk.name} skeleton has no target bone lengths; pass lengths")
        lengths = sk.bone_lengths
    quat, root = root_from_features(x)
    T, J = len(x), sk.num_joints
    local = cont6d_to_matrix(x[:, feature_slices(sk).rotations].reshape(T, J - 1, 6))
    xp = namespace(x)
    raw = xp.asarray(np.asarray(sk.offsets_array) * np.asarray(lengths, dtype=np.float64)[:, None], dtype=x.dtype,
                     device=device(x))
    pos: list = [None] * J
    pos[0] = root
    root_m = quat_to_matrix(quat)
    for chain in sk.chains:
        acc = root_m
        for p, c in zip(chain[:-1], chain[1:]):
            acc = acc @ local[:, c - 1]
            pos[c] = pos[p] + acc @ raw[c]
    return xp.stack(pos, axis=1)


def features_in_frames_of(joints: np.ndarray, reference: np.ndarray, skeleton: str | Skeleton = "humanml3d", *,
                          rotations: str = "ik") -> np.ndarray:
    """Features (T, D) that decode exactly to ``joints`` (T, J, 3), written in the body frames of
    ``reference`` features (T, D): its yaw channel and foot contacts are kept, root, positions and
    velocities are computed from the joints in those frames (the last frame's velocity by extrapolation).
    The joints' first root must sit at the XZ origin, where :func:`joints_from_features` starts.

    ``rotations``: "ik" computes the 6D rotations from the joints (HumanML3D's inverse kinematics in the
    reference's frames, as real features have them); "keep" keeps the reference's rotation channels.
    """
    sk = get_skeleton(skeleton)
    ref = np.asarray(reference, dtype=np.float64)
    _check_features(ref, sk)
    pos = _check_joints(joints, sk, min_frames=2)
    if len(pos) != len(ref):
        raise MotionFormatError(f"{len(pos)} frames of joints but {len(ref)} of reference features")
    if rotations not in ("ik", "keep"):
        raise MotionFormatError(f"rotations must be 'ik' or 'keep', got {rotations!r}")
    quat = root_from_features(ref)[0]  # (T, 4) world -> body frame
    s = feature_slices(sk)
    T, J = pos.shape[:2]
    ext = np.concatenate([pos, 2 * pos[-1:] - pos[-2:-1]])  # one extrapolated frame for the last velocity
    q_next = np.concatenate([quat[1:], quat[-1:]])
    out = ref.copy()
    out[:, s.root_xz_velocity] = qrot(q_next, ext[1:, 0] - ext[:-1, 0])[:, [0, 2]]
    out[:, s.root_height] = pos[:, 0, 1:2]
    local = pos[:, 1:] - pos[:, :1] * np.array([1.0, 0.0, 1.0])
    out[:, s.positions] = qrot(np.broadcast_to(quat[:, None], local.shape[:-1] + (4,)), local).reshape(T, -1)
    step = ext[1:] - ext[:-1]
    out[:, s.velocities] = qrot(np.broadcast_to(quat[:, None], step.shape[:-1] + (4,)), step).reshape(T, -1)
    if rotations == "ik":
        quats = inverse_kinematics(pos, sk, root=quat)
        out[:, s.rotations] = quat_to_cont6d(quats[:, 1:]).reshape(T, -1)
    return out


def _signs(values: list[float], like):
    return namespace(like).asarray(values, dtype=like.dtype, device=device(like))


def mirror_joints(joints, skeleton: str | Skeleton = "humanml3d"):
    """Left/right mirror (..., J, 3): negate X and swap left and right joints (HumanML3D's M-copies)."""
    sk = get_skeleton(skeleton)
    out = joints[..., sk.mirror_permutation, :]
    return out * _signs([-1.0, 1.0, 1.0], out)


def mirror_features(features, skeleton: str | Skeleton = "humanml3d"):
    """Mirror features (..., D) directly, equal to features_from_joints(mirror_joints(joints)).

    Negates yaw velocity and every X component, swaps left/right joints and contacts; a rotation R
    becomes M R M with M = diag(-1, 1, 1).
    """
    sk = get_skeleton(skeleton)
    J = sk.num_joints
    s = feature_slices(sk)
    perm = sk.mirror_permutation
    xp = namespace(features)
    if not xp.isdtype(features.dtype, "real floating"):
        features = xp.astype(features, xp.float32)
    lead = tuple(features.shape[:-1])
    out = features + 0.0  # a copy (differentiable for tensors)
    out[..., 0] = -features[..., 0]
    out[..., 1] = -features[..., 1]
    ric = features[..., s.positions].reshape(lead + (J - 1, 3))[..., perm[1:] - 1, :]
    out[..., s.positions] = (ric * _signs([-1.0, 1.0, 1.0], out)).reshape(lead + (-1,))
    rot = features[..., s.rotations].reshape(lead + (J - 1, 6))[..., perm[1:] - 1, :]
    out[..., s.rotations] = (rot * _signs([1.0, -1.0, -1.0, -1.0, 1.0, 1.0], out)).reshape(lead + (-1,))
    vel = features[..., s.velocities].reshape(lead + (J, 3))[..., perm, :]
    out[..., s.velocities] = (vel * _signs([-1.0, 1.0, 1.0], out)).reshape(lead + (-1,))
    c = s.contacts.start
    out[..., c:c + 2] = features[..., c + 2:c + 4]
    out[..., c + 2:c + 4] = features[..., c:c + 2]
    return out
