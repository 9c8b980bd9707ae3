"""Footskate cleanup on a rigid body: a short L-BFGS optimisation of joint rotations and the root path.

The body is a :class:`~stablemofusion.motion.rigid.RigidMotion`, so the cleanup moves rotations and the
root, never bone lengths. Losses (positions in centimetres so the terms are O(1)):
  pose    - joints stay close to the input (root-relative displacement; legs are freer than the body);
  anchor  - every contact joint stays, for its contact interval, at its mean position over the interval
            (planted toes on the floor, y = 0; ankles at their mean height);
  root    - the root velocity is kept, and (``w_root_offset``) so is the root's path itself: the legs
            absorb a drift of the body over planted feet, and a foot hovering over the floor is lowered
            by bending its leg, instead of the whole body being moved;
  vgrf    - the predicted vertical ground reaction forces are kept (only with a vGRF model);
plus the pose change kept smooth (no popping at contact boundaries) and a floor term against penetration.

A contact never holds a foot the body has left (:func:`anchor_targets`): an interval in which the foot
travels further than ``max_anchor_shift`` from its anchor is split into shorter contacts, each with its
own anchor, and a frame whose anchor lies beyond the leg's reach from the hip is not anchored.

Back to features (:func:`cleanup_features`): the cleaned body is written in the body frames of the input
features (:func:`~stablemofusion.motion.rigid.rigid_to_features`), so the features decode to its joints.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import SMFError
from ..motion.features import feature_slices, features_from_joints
from ..motion.rigid import (CM, DEFAULT_FIT, RigidFitConfig, RigidMotion, fit_rigid, optimise_pose,
                            rigid_from_features_many, rigid_to_features)
from .contacts import HML_FOOT_JOINTS, KinematicContactConfig, contacts_from_vgrf, kinematic_contacts, runs

VgrfModel = Callable  # torch: (B, T, 22, 3) metres, Y up, 20 fps -> (B, T, 2, 16); the vGRF route needs torch
LEG_JOINTS = (1, 2, 4, 5, 7, 8, 10, 11)
# the chain from each contact joint (left ankle, left toe, right ankle, right toe) up to its hip
FOOT_CHAINS = ((1, 4, 7), (1, 4, 7, 10), (2, 5, 8), (2, 5, 8, 11))
CONTACT_ROUTES = ("kinematic", "vgrf")
# looser than the detector's defaults (0.5/0.8 m/s, 5/8 cm): a sliding foot is still a planted foot that must
# be pinned, and a generated motion's floor level is noisy (chosen on the validation split, docs/footskate.md)
CLEANUP_CONTACTS = KinematicContactConfig(speed_on=2.0, speed_off=2.5, height_on=0.06, height_off=0.08)
# a joints file keeps its own skeleton: bone lengths are the motion's median
JOINTS_FIT = RigidFitConfig(bone_lengths="median", start="positions")


@dataclass(frozen=True)
class CleanupConfig:
    """Weights and solver settings of :func:`cleanup_rigid`."""

    contacts: str = "kinematic"  # or "vgrf" (needs a vGRF model)
    iterations: int = 20  # L-BFGS iterations
    w_pose: float = 1.0
    leg_pose_scale: float = 0.1  # pose weight of hips, knees, ankles and toes relative to the body
    w_anchor: float = 100.0
    w_root: float = 1.0
    w_root_offset: float = 10.0  # keeps the root's path (0: the body may be moved back over its feet)
    w_vgrf: float = 1.0
    w_smooth: float = 1.0
    w_floor: float = 10.0
    anchor_floor: bool = True  # planted toes at y = 0; False: at their mean height over the contact
    max_anchor_shift: float = 0.25  # m: a contact whose foot travels further from its anchor is split
    reach_margin: float = 0.05  # m: an anchor further than the leg's length plus this from the hip is not held
    kinematic: KinematicContactConfig = CLEANUP_CONTACTS  # frozen, so one shared default is safe


@dataclass
class CleanupResult:
    """Cleaned joints (T, 22, 3) in the input's frame, the contacts (T, 4) that were enforced, and the cleaned
    rigid body the joints come from."""

    joints: np.ndarray
    contacts: np.ndarray
    motion: RigidMotion


def split_contact(points: np.ndarray, max_shift: float) -> list[tuple[int, int]]:
    """Split one contact interval of a joint's positions (n, 3) into [(start, stop)) pieces in which no
    position lies further than ``max_shift`` (m, horizontally) from the piece's mean: a piece grows frame by
    frame until one of its positions strays, and the next piece starts at its last frame."""
    pieces, a, n = [], 0, len(points)
    while True:
        xz = points[a:, [0, 2]]
        means = np.cumsum(xz, 0) / np.arange(1, len(xz) + 1)[:, None]  # row m: the mean of the first m + 1
        far = np.linalg.norm(xz[None] - means[:, None], axis=-1)  # (m, i): position i from that mean
        worst = np.where(np.tri(len(xz), dtype=bool), far, 0.0).max(1)  # over the positions i <= m
        over = np.flatnonzero(worst > max_shift)
        if not len(over):
            pieces.append((a, n))
            return pieces
        b = a + int(over[0])  # the piece a .. b strays: it ends before b, the next starts at b - 1
        pieces.append((a, b))
        a = b


def anchor_targets(joints: np.ndarray, contacts: np.ndarray, *, floor: bool = True, max_shift: float = np.inf,
                   bone_lengths: np.ndarray | None = None, reach_margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Targets (T, 4, 3) and a mask (T, 4) for the foot joints (left ankle, left toe, right ankle, right toe).

    Each contact interval is pinned to the joint's mean position over the interval (the point that moves
    it least), not below the floor; with ``floor`` planted toes are put on the floor (y = 0). Ankles keep
    their mean height: how high a planted ankle sits depends on heel and toe, and lowering it with its toe
    bent the legs of generated motions and cost FID in our validation runs. An interval in which the joint
    travels further than ``max_shift`` (m) from the mean is split (see :func:`split_contact`); with
    ``bone_lengths`` (22,) a frame whose anchor lies further from the hip than the leg can reach (the sum of
    the bones from hip to the joint, plus ``reach_margin`` m that a small move of the pelvis makes up) is left
    free: the body has left that foot.
    """
    feet = joints[:, list(HML_FOOT_JOINTS)]
    target = np.zeros_like(feet)
    mask = np.zeros(contacts.shape, dtype=bool)
    for k in range(4):
        for a, b in runs(contacts[:, k]):
            for a2, b2 in split_contact(feet[a:b, k], max_shift):
                p = feet[a + a2:a + b2, k].mean(0)
                p[1] = 0.0 if floor and k in (1, 3) else max(0.0, p[1])
                target[a + a2:a + b2, k] = p
                mask[a + a2:a + b2, k] = True
        if bone_lengths is not None:
            chain = FOOT_CHAINS[k]
            reach = float(np.sum(np.asarray(bone_lengths)[list(chain[1:])])) + reach_margin
            mask[:, k] &= np.linalg.norm(target[:, k] - joints[:, chain[0]], axis=-1) <= reach
    return target, mask


def detect_contacts(joints: np.ndarray, fps: float, config: CleanupConfig,
                    vgrf_model: VgrfModel | None = None) -> np.ndarray:
    """Contacts (T, 4) by the route named in ``config.contacts``."""
    if config.contacts == "kinematic":
        return kinematic_contacts(joints, fps, config=config.kinematic)
    if config.contacts == "vgrf":
        if vgrf_model is None:
            raise SMFError("contacts='vgrf' needs a vGRF model (a distilled 22-joint model or UnderPressure)")
        import torch

        with torch.no_grad():
            f = vgrf_model(torch.as_tensor(joints, dtype=torch.float32)[None])[0].double().numpy()
        return contacts_from_vgrf(f, fps)
    raise SMFError(f"unknown contact route {config.contacts!r}; choose from {', '.join(CONTACT_ROUTES)}")


def cleanup_rigid(motion: RigidMotion, fps: float = 20.0, config: CleanupConfig = CleanupConfig(), *,
                  vgrf_model: VgrfModel | None = None, contacts: np.ndarray | None = None) -> CleanupResult:
    """Remove foot skating from a rigid HumanML3D motion (metres, Y up, floor y = 0) at ``fps``: moves its
    rotations and root, never its bone lengths."""
    if motion.skeleton != "humanml3d" or len(motion) < 2:
        raise SMFError(f"footskate cleanup needs a HumanML3D motion of at least 2 frames, got {motion.skeleton} "
                       f"with {len(motion)}")
    x0 = motion.joints()
    c = detect_contacts(x0, fps, config, vgrf_model) if contacts is None else np.asarray(contacts, bool)
    target, mask = anchor_targets(x0, c, floor=config.anchor_floor, max_shift=config.max_anchor_shift,
                                  bone_lengths=motion.bone_lengths, reach_margin=config.reach_margin)
    loss_fn = _cleanup_loss(x0 * CM, target * CM, mask, config, vgrf_model)
    out = optimise_pose(motion, loss_fn, config.iterations)
    return CleanupResult(out.joints(), c, out)


def _cleanup_loss(X0: np.ndarray, tgt: np.ndarray, mask: np.ndarray, config: CleanupConfig,
                  vgrf_model: VgrfModel | None):
    """The loss of :func:`cleanup_rigid` (module docstring) and its gradient, on joints X (T, 22, 3) cm and the
    root's shift (T, 3) cm: (value, dvalue/dX, dvalue/dshift)."""
    T, J = X0.shape[:2]
    m = mask.astype(np.float64)[..., None]
    n_anchor = max(1.0, float(mask.sum()))
    w_joint = np.ones(J)
    w_joint[list(LEG_JOINTS)] = config.leg_pose_scale
    feet = list(HML_FOOT_JOINTS)
    vgrf = _vgrf_term(X0, vgrf_model) if vgrf_model is not None and config.w_vgrf > 0 else None

    def loss(X: np.ndarray, shift: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        local = X - X0 - shift[:, None]  # the pose's own change (the root's is zero)
        step = shift[1:] - shift[:-1]
        moved = local[1:] - local[:-1]
        below = np.maximum(-X[..., 1], 0.0)
        off = (X[:, feet] - tgt) * m
        value = (config.w_pose * ((local ** 2).sum(-1) * w_joint).mean()
                 + config.w_anchor * (off ** 2).sum() / n_anchor
                 + config.w_root * (step ** 2).sum(-1).mean()
                 + config.w_root_offset * (shift ** 2).sum(-1).mean()
                 + config.w_smooth * (moved ** 2).sum(-1).mean()
                 + config.w_floor * (below ** 2).mean())
        g_local = config.w_pose * 2 * local * w_joint[:, None] / (T * J)
        g_moved = config.w_smooth * 2 * moved / ((T - 1) * J)
        g_local[1:] += g_moved
        g_local[:-1] -= g_moved
        gX = g_local.copy()
        gX[:, feet] += config.w_anchor * 2 * off / n_anchor
        gX[..., 1] -= config.w_floor * 2 * below / (T * J)
        g_step = config.w_root * 2 * step / (T - 1)
        g_shift = config.w_root_offset * 2 * shift / T - g_local.sum(1)
        g_shift[1:] += g_step
        g_shift[:-1] -= g_step
        if vgrf is not None:
            v, g = vgrf(X)
            value += config.w_vgrf * v
            gX += config.w_vgrf * g
        return float(value), gX, g_shift

    return loss


def _vgrf_term(X0: np.ndarray, vgrf_model: VgrfModel):
    """The vGRF term (100 x the mean squared change of the predicted forces) and its gradient, through the torch
    model (the vGRF route needs torch)."""
    import torch

    with torch.no_grad():
        g0 = vgrf_model(torch.as_tensor(X0[None] / CM, dtype=torch.float32)).double()

    def term(X: np.ndarray) -> tuple[float, np.ndarray]:
        x = torch.tensor(X, dtype=torch.float64, requires_grad=True)
        v = 100.0 * ((vgrf_model(x[None].float() / CM).double() - g0) ** 2).mean()
        v.backward()
        return float(v.detach()), x.grad.numpy()

    return term


def cleanup_joints(joints: np.ndarray, fps: float = 20.0, config: CleanupConfig = CleanupConfig(), *,
                   vgrf_model: VgrfModel | None = None, contacts: np.ndarray | None = None,
                   rigid: RigidFitConfig = JOINTS_FIT) -> CleanupResult:
    """Remove foot skating from joints (T, 22, 3) (metres, Y up, floor y = 0) at ``fps``: fits a rigid body
    (bone lengths by ``rigid``: the motion's median by default), then :func:`cleanup_rigid`."""
    x0 = np.asarray(joints, dtype=np.float64)
    if x0.ndim != 3 or x0.shape[1:] != (22, 3) or len(x0) < 2:
        raise SMFError(f"expected joints of shape (T>=2, 22, 3), got {tuple(x0.shape)}")
    return cleanup_rigid(fit_rigid(x0, "humanml3d", rigid), fps, config, vgrf_model=vgrf_model, contacts=contacts)


def features_from_cleaned(joints: np.ndarray) -> np.ndarray:
    """Joints (T, 22, 3) -> features (T, 263): appends one extrapolated frame, since
    :func:`features_from_joints` returns one frame fewer; bone lengths and heights are kept as they are."""
    j = np.asarray(joints, dtype=np.float64)
    ext = np.concatenate([j, 2 * j[-1:] - j[-2:-1]], 0)
    feats = features_from_joints(ext, uniform=False)
    # features_from_joints puts the lowest joint of the motion at y = 0; keep the optimised heights instead
    # (the floor loss already lifted what was below the floor, frame by frame)
    lift = ext[..., 1].min()
    sl = feature_slices("humanml3d")
    feats[:, sl.root_height] += lift
    feats[:, sl.positions.start + 1:sl.positions.stop:3] += lift
    return feats


def cleanup_features_many(features: list[np.ndarray], config: CleanupConfig = CleanupConfig(), *,
                          vgrf_model: VgrfModel | None = None, fps: float = 20.0,
                          rigid: RigidFitConfig = DEFAULT_FIT) -> list[tuple[np.ndarray, RigidMotion]]:
    """HumanML3D features (T_i, 263) in dataset units -> per motion the cleaned features (T_i, 263) and the cleaned
    rigid body they decode to: the rigid fits of all the features together (``rigid``; each motion's fit is the
    one it gets alone), :func:`cleanup_rigid` of each, then each body written in its input's body frames
    (:func:`~stablemofusion.motion.rigid.rigid_to_features`)."""
    fs = [np.asarray(f, dtype=np.float64) for f in features]
    for f in fs:
        if f.ndim != 2 or f.shape[1] != 263 or len(f) < 2:
            raise SMFError(f"expected features of shape (T>=2, 263), got {tuple(f.shape)}")
    out = []
    for body, f in zip(rigid_from_features_many(fs, "humanml3d", rigid), fs):
        res = cleanup_rigid(body, fps, config, vgrf_model=vgrf_model)
        motion, written = rigid_to_features(res.motion, f, rigid)
        out.append((written, motion))
    return out


def cleanup_features(features: np.ndarray, config: CleanupConfig = CleanupConfig(), *,
                     vgrf_model: VgrfModel | None = None, fps: float = 20.0,
                     rigid: RigidFitConfig = DEFAULT_FIT) -> tuple[np.ndarray, RigidMotion]:
    """HumanML3D features (T, 263) in dataset units -> cleaned features (T, 263) and the cleaned rigid body
    they decode to (:func:`cleanup_features_many` of one)."""
    return cleanup_features_many([features], config, vgrf_model=vgrf_model, fps=fps, rigid=rigid)[0]


def align_yaw_xz(moving: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Rotate ``moving`` (T, J, 3) about +Y and shift it in XZ to best match ``fixed`` (least squares).

    Features only fix a motion up to its first-frame heading and start point; use this before comparing
    joints decoded from two feature arrays. Heights are left untouched.
    """
    a = np.asarray(moving, np.float64)
    b = np.asarray(fixed, np.float64)
    pa, pb = a[..., [0, 2]].reshape(-1, 2), b[..., [0, 2]].reshape(-1, 2)
    ca, cb = pa.mean(0), pb.mean(0)
    h = (pa - ca).T @ (pb - cb)
    theta = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    r = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    out = a.copy()
    out[..., [0, 2]] = (a[..., [0, 2]] - ca) @ r.T + cb
    return out
