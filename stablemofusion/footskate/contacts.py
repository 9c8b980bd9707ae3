"""Foot contacts, two routes: kinematic (heights and speeds with hysteresis) and from vGRF.

Every detector returns a boolean (T, 4) array in HumanML3D's contact order: left ankle (heel), left toe,
right ankle (heel), right toe.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SMFError

HML_FOOT_JOINTS = (7, 10, 8, 11)  # left ankle, left toe, right ankle, right toe (HumanML3D)
UP_FOOT_JOINTS = (21, 22, 17, 18)  # the same on UnderPressure's 23-joint skeleton
HEEL_CELLS = slice(0, 6)  # insole cells under the heel; 6..15 lie under the forefoot (read off S1_Hopping)
TOE_CELLS = slice(6, 16)


@dataclass(frozen=True)
class KinematicContactConfig:
    """Thresholds of the kinematic detector. Heights are above the joint type's own floor level (the lower
    2nd percentile of the left/right joint's height over the motion), speeds are 3D joint speeds."""

    height_on: float = 0.05  # m: a contact may start below this height ...
    height_off: float = 0.08  # m: ... and ends above this one (hysteresis)
    speed_on: float = 0.50  # m/s: a contact may start below this speed ...
    speed_off: float = 0.80  # m/s: ... and ends above this one
    min_contact: float = 0.06  # s: shorter contacts are dropped
    min_gap: float = 0.06  # s: shorter gaps between contacts are filled
    floor_percentile: float = 2.0


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(T,) bool -> [(start, stop)) of every run of True."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.flatnonzero(np.diff(m.astype(np.int8)))
    return list(zip(d[::2].tolist(), d[1::2].tolist()))


def clean_durations(mask: np.ndarray, min_on: int, min_gap: int) -> np.ndarray:
    """(T, K) bool: fill interior gaps shorter than ``min_gap`` frames, then drop runs shorter than
    ``min_on`` frames."""
    out = np.array(mask, dtype=bool, copy=True)
    for k in range(out.shape[1]):
        col = out[:, k]
        for a, b in runs(~col):
            if 0 < a and b < len(col) and b - a < min_gap:
                col[a:b] = True
        for a, b in runs(col):
            if b - a < min_on:
                col[a:b] = False
    return out


def _hysteresis(enter: np.ndarray, stay: np.ndarray) -> np.ndarray:
    """(T, K): contact starts where ``enter`` holds and lasts while ``stay`` holds (enter implies stay)."""
    out = np.zeros_like(enter, dtype=bool)
    state = enter[0].copy()
    out[0] = state
    for t in range(1, len(enter)):
        state = np.where(state, stay[t], enter[t])
        out[t] = state
    return out


def _percentile(x: np.ndarray, q: float) -> np.ndarray:
    """np.percentile(x, q, axis=0) with linear interpolation, without its overhead: (T, K) -> (K,)."""
    s = np.sort(x, axis=0)
    pos = q / 100.0 * (len(s) - 1)
    lo = int(np.floor(pos))
    hi = min(lo + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (pos - lo)


def kinematic_contacts(joints: np.ndarray, fps: float, *, foot_joints: tuple[int, int, int, int] = HML_FOOT_JOINTS,
                       up_axis: int = 1, config: KinematicContactConfig = KinematicContactConfig()) -> np.ndarray:
    """Joints (T, J, 3) in metres at ``fps`` -> contacts (T, 4) bool for ``foot_joints`` (left ankle, left toe,
    right ankle, right toe). Needs no model or file; works for any skeleton given its foot joints and up axis."""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[-1] != 3 or len(joints) < 2:
        raise SMFError(f"expected joints of shape (T>=2, J, 3), got {tuple(joints.shape)}")
    if not fps > 0:
        raise SMFError(f"fps must be positive, got {fps}")
    feet = joints[:, list(foot_joints)]
    h = feet[..., up_axis]
    floor = _percentile(h, config.floor_percentile)
    floor = np.minimum(floor[[0, 1, 0, 1]], floor[[2, 3, 2, 3]])  # ankles share a level, toes share a level
    h = h - floor
    speed = np.linalg.norm(np.gradient(feet, axis=0), axis=-1) * fps
    enter = (h < config.height_on) & (speed < config.speed_on)
    stay = (h < config.height_off) & (speed < config.speed_off)
    c = _hysteresis(enter, stay | enter)
    return clean_durations(c, max(1, round(config.min_contact * fps)), max(1, round(config.min_gap * fps)))


def contacts_from_vgrf(forces: np.ndarray, fps: float, *, foot_threshold: float = 0.10,
                       location_threshold: float = 0.05, smooth: float = 0.03) -> np.ndarray:
    """vGRF (T, 2, 16) (body weight, foot 0 = left) -> contacts (T, 4) bool.

    A foot is in contact when it carries at least ``foot_threshold`` of the body weight, and its heel (toe)
    when the heel (forefoot) cells carry at least ``location_threshold``; runs and gaps shorter than
    ``smooth`` seconds are removed.
    """
    f = np.asarray(forces, dtype=np.float64)
    if f.ndim != 3 or f.shape[1:] != (2, 16):
        raise SMFError(f"expected vGRF of shape (T, 2, 16), got {tuple(f.shape)}")
    foot = f.sum(-1) >= foot_threshold
    heel = foot & (f[..., HEEL_CELLS].sum(-1) >= location_threshold)
    toe = foot & (f[..., TOE_CELLS].sum(-1) >= location_threshold)
    c = np.stack([heel[:, 0], toe[:, 0], heel[:, 1], toe[:, 1]], -1)
    n = max(1, round(smooth * fps))
    return clean_durations(c, n, n)


def contacts_from_underpressure_labels(contacts: np.ndarray) -> np.ndarray:
    """UnderPressure's measured contacts (T, 2, 2) [toe|heel, left|right] -> (T, 4) in our order."""
    c = np.asarray(contacts, dtype=bool)
    return np.stack([c[:, 1, 0], c[:, 0, 0], c[:, 1, 1], c[:, 0, 1]], -1)


def contact_f1(pred: np.ndarray, true: np.ndarray) -> float:
    """F1 score of boolean contact arrays of equal shape (all channels pooled)."""
    p, t = np.asarray(pred, bool), np.asarray(true, bool)
    tp = float((p & t).sum())
    denom = float(p.sum() + t.sum())
    return 2.0 * tp / denom if denom else 1.0
