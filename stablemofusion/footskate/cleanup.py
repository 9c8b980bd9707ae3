"""Footskate cleanup: a short L-BFGS optimisation of joint positions with the paper's four losses.

Losses (positions in centimetres so the terms are O(1)):
  pose    - joints stay close to the input (root-relative displacement; legs are freer than the body);
  anchor  - every contact joint stays, for its whole contact interval, at its mean position over the
            interval (planted toes on the floor, y = 0; ankles at their mean height);
  root    - the root velocity is kept, and (``w_root_offset``) so is the root's path itself: the legs
            absorb a drift of the body over planted feet, and a foot hovering over the floor is lowered
            by bending its leg, instead of the whole body being moved;
  vgrf    - the predicted vertical ground reaction forces are kept (only with a vGRF model);
plus two regularisers that keep the result a valid motion: bone lengths kept and joint velocities kept
(no popping at contact boundaries), and a floor term against penetration.

Back to features (:func:`edit_features`): the change the cleanup made to the joints is turned into a change
of the features (features of the cleaned joints minus features of the input joints) and added to the input
features, so every dimension the cleanup did not touch (e.g. a generated motion's joint rotations) is kept
exactly; recomputing all features from positions alone would replace a model's rotations by inverse
kinematics of its positions, which on our shipped model costs far more FID (docs/footskate.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from ..errors import SMFError
from ..motion.features import feature_slices, features_from_joints, joints_from_features
from ..motion.skeleton import get_skeleton
from .contacts import HML_FOOT_JOINTS, KinematicContactConfig, contacts_from_vgrf, kinematic_contacts, runs

VgrfModel = Callable[[torch.Tensor], torch.Tensor]  # (B, T, 22, 3) metres, Y up, 20 fps -> (B, T, 2, 16)
LEG_JOINTS = (1, 2, 4, 5, 7, 8, 10, 11)
CONTACT_ROUTES = ("kinematic", "vgrf")
# looser than the detector's defaults (0.5/0.8 m/s, 5/8 cm): a sliding foot is still a planted foot that must
# be pinned, and a generated motion's floor level is noisy (chosen on the validation split, docs/footskate.md)
CLEANUP_CONTACTS = KinematicContactConfig(speed_on=2.0, speed_off=2.5, height_on=0.06, height_off=0.08)


@dataclass(frozen=True)
class CleanupConfig:
    """Weights and solver settings of :func:`cleanup_joints`."""

    contacts: str = "kinematic"  # or "vgrf" (needs a vGRF model)
    iterations: int = 20  # L-BFGS iterations
    w_pose: float = 1.0
    leg_pose_scale: float = 0.1  # pose weight of hips, knees, ankles and toes relative to the body
    w_anchor: float = 100.0
    w_root: float = 1.0
    w_root_offset: float = 10.0  # keeps the root's path (0: the body may be moved back over its feet)
    w_vgrf: float = 1.0
    w_bone: float = 10.0
    w_smooth: float = 1.0
    w_floor: float = 10.0
    anchor_floor: bool = True  # planted toes at y = 0; False: at their mean height over the contact
    kinematic: KinematicContactConfig = CLEANUP_CONTACTS  # frozen, so one shared default is safe


@dataclass
class CleanupResult:
    """Cleaned joints (T, 22, 3) in the input's frame, and the contacts (T, 4) that were enforced."""

    joints: np.ndarray
    contacts: np.ndarray


def anchor_targets(joints: np.ndarray, contacts: np.ndarray, *, floor: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Targets (T, 4, 3) and a mask (T, 4) for the foot joints (left ankle, left toe, right ankle, right toe).

    Each contact interval is pinned to the joint's mean position over the interval (the point that moves
    it least), not below the floor; with ``floor`` planted toes are put on the floor (y = 0). Ankles keep
    their mean height: how high a planted ankle sits depends on heel and toe, and lowering it with its toe
    bent the legs of generated motions and cost FID in our validation runs.
    """
    feet = joints[:, list(HML_FOOT_JOINTS)]
    target = np.zeros_like(feet)
    mask = np.zeros(contacts.shape, dtype=bool)
    for k in range(4):
        for a, b in runs(contacts[:, k]):
            p = feet[a:b, k].mean(0)
            p[1] = 0.0 if floor and k in (1, 3) else max(0.0, p[1])
            target[a:b, k] = p
            mask[a:b, k] = True
    return target, mask


def detect_contacts(joints: np.ndarray, fps: float, config: CleanupConfig,
                    vgrf_model: VgrfModel | None = None) -> np.ndarray:
    """Contacts (T, 4) by the route named in ``config.contacts``."""
    if config.contacts == "kinematic":
        return kinematic_contacts(joints, fps, config=config.kinematic)
    if config.contacts == "vgrf":
        if vgrf_model is None:
            raise SMFError("contacts='vgrf' needs a vGRF model (a distilled 22-joint model or UnderPressure)")
        with torch.no_grad():
            f = vgrf_model(torch.as_tensor(joints, dtype=torch.float32)[None])[0].double().numpy()
        return contacts_from_vgrf(f, fps)
    raise SMFError(f"unknown contact route {config.contacts!r}; choose from {', '.join(CONTACT_ROUTES)}")


def cleanup_joints(joints: np.ndarray, fps: float = 20.0, config: CleanupConfig = CleanupConfig(), *,
                   vgrf_model: VgrfModel | None = None, contacts: np.ndarray | None = None) -> CleanupResult:
    """Remove foot skating from joints (T, 22, 3) (metres, Y up, floor y = 0) at ``fps``."""
    x0 = np.asarray(joints, dtype=np.float64)
    if x0.ndim != 3 or x0.shape[1:] != (22, 3) or len(x0) < 2:
        raise SMFError(f"expected joints of shape (T>=2, 22, 3), got {tuple(x0.shape)}")
    c = detect_contacts(x0, fps, config, vgrf_model) if contacts is None else np.asarray(contacts, bool)
    target, mask = anchor_targets(x0, c, floor=config.anchor_floor)
    parents = np.array(get_skeleton("humanml3d").parents)
    T = len(x0)
    S = 100.0  # metres -> centimetres
    X0 = torch.as_tensor(x0 * S, dtype=torch.float32)
    tgt = torch.as_tensor(target * S, dtype=torch.float32)
    m = torch.as_tensor(mask, dtype=torch.float32)[..., None]
    n_anchor = max(1.0, float(mask.sum()))
    bones0 = torch.linalg.vector_norm(X0[:, 1:] - X0[:, parents[1:]], dim=-1)
    w_joint = torch.ones(22)
    w_joint[list(LEG_JOINTS)] = config.leg_pose_scale
    w_joint[0] = 0.0  # the root moves through its own displacement
    use_vgrf = vgrf_model is not None and config.w_vgrf > 0
    if use_vgrf:
        with torch.no_grad():
            g0 = vgrf_model(X0[None] / S)
    root = torch.zeros(T, 1, 3, requires_grad=True)
    local = torch.zeros(T, 22, 3, requires_grad=True)
    opt = torch.optim.LBFGS([root, local], lr=1.0, max_iter=config.iterations, history_size=10,
                            line_search_fn="strong_wolfe")
    foot_idx = list(HML_FOOT_JOINTS)

    def loss_fn() -> torch.Tensor:
        opt.zero_grad()
        X = X0 + root + local
        loss = config.w_pose * ((local ** 2).sum(-1) * w_joint).mean()
        loss = loss + config.w_anchor * (((X[:, foot_idx] - tgt) ** 2) * m).sum() / n_anchor
        loss = loss + config.w_root * ((root[1:] - root[:-1]) ** 2).sum(-1).mean()
        loss = loss + config.w_root_offset * (root ** 2).sum(-1).mean()
        loss = loss + config.w_smooth * ((local[1:] - local[:-1]) ** 2).sum(-1).mean()
        bones = torch.linalg.vector_norm(X[:, 1:] - X[:, parents[1:]], dim=-1)
        loss = loss + config.w_bone * ((bones - bones0) ** 2).mean()
        loss = loss + config.w_floor * (torch.relu(-X[..., 1]) ** 2).mean()
        if use_vgrf:
            loss = loss + config.w_vgrf * 100.0 * ((vgrf_model(X[None] / S) - g0) ** 2).mean()
        loss.backward()
        return loss

    opt.step(loss_fn)
    with torch.no_grad():
        out = ((X0 + root + local) / S).double().numpy()
    return CleanupResult(out, c)


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


def edit_features(features: np.ndarray, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """Apply a joint edit to features: ``features`` (T, 263) decode to ``before`` (T, 22, 3); returns
    features that decode to ``after`` and equal ``features`` wherever the edit changes nothing.

    The change is ``features_from_cleaned(after) - features_from_cleaned(before)``; foot-contact labels
    are taken from ``after`` on the frames where they change."""
    f = np.asarray(features, dtype=np.float64)
    new = features_from_cleaned(after)
    d = new - features_from_cleaned(before)
    out = f + d
    sl = feature_slices("humanml3d").contacts
    out[:, sl] = np.where(d[:, sl] != 0, new[:, sl], f[:, sl])
    return out


def cleanup_features(features: np.ndarray, config: CleanupConfig = CleanupConfig(), *,
                     vgrf_model: VgrfModel | None = None, fps: float = 20.0) -> np.ndarray:
    """HumanML3D features (T, 263) in dataset units -> cleaned features (T, 263) (see :func:`edit_features`)."""
    f = np.asarray(features, dtype=np.float64)
    if f.ndim != 2 or f.shape[1] != 263 or len(f) < 2:
        raise SMFError(f"expected features of shape (T>=2, 263), got {tuple(f.shape)}")
    joints = joints_from_features(f)
    res = cleanup_joints(joints, fps, config, vgrf_model=vgrf_model)
    return edit_features(f, joints, res.joints)


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
