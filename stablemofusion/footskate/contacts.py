"""Foot contacts, two routes: kinematic (heights and speeds with hysteresis) and from vGRF.

Every detector returns a boolean (T, 4) array in HumanML3D's contact order: left ankle (heel), left toe,
right ankle (heel), right toe.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import SMFError
from ..motion import timeseries as ts
from ..motion.arrays import device, namespace

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


def durations_cleaned(c, min_on: int, min_gap: int):
    """(N, T) bool: interior gaps shorter than ``min_gap`` frames filled, then runs shorter than ``min_on`` frames
    dropped (array API, loop-free)."""
    T = ts.count(c)
    before, after = ts.last_true(c), ts.next_true(c)  # around a gap: its start - 1 and its end
    fill = ~c & (before >= 0) & (after < T) & (after - before - 1 < min_gap)
    c = c | fill
    start, stop = ts.last_true(~c) + 1, ts.next_true(~c)  # of the run a contact frame is in
    return c & (stop - start >= min_on)


def clean_durations(mask: np.ndarray, min_on: int, min_gap: int) -> np.ndarray:
    """(T, K) bool: fill interior gaps shorter than ``min_gap`` frames, then drop runs shorter than
    ``min_on`` frames."""
    m = np.asarray(mask, dtype=bool)
    return durations_cleaned(m.T, min_on, min_gap).T.copy()


def hysteresis(enter, stay):
    """(N, T) bool: a contact starts where ``enter`` holds and lasts while ``stay`` holds (enter implies stay): on
    at t when the last frame that entered comes after the last frame that could not stay."""
    return ts.last_true(enter) > ts.last_true(~(stay | enter))


def contacts_of_feet(feet, fps: float, config: KinematicContactConfig, up_axis: int = 1):
    """Kinematic contacts of foot joints ``feet`` (B, T, 4, 3) metres (left ankle, left toe, right ankle, right toe)
    at ``fps``: (B, T, 4) bool (array API, loop-free; T >= 2)."""
    xp = namespace(feet)
    B, T = feet.shape[0], feet.shape[1]
    h = feet[..., up_axis]  # (B, T, 4)
    s = ts.sorted_in_time(h)  # the floor: the lower percentile of each joint's height, linearly interpolated
    last = ts.count(h) - 1  # (1,) as an array: a traced T is symbolic
    pos = xp.astype(last, h.dtype) * ts.const(h, config.floor_percentile / 100.0)
    lo = xp.astype(xp.floor(pos), xp.int64)
    hi = xp.minimum(lo + 1, last)
    frac = pos - xp.astype(lo, pos.dtype)
    at_lo = xp.take(s, lo, axis=1)[:, 0]
    floor = at_lo + (xp.take(s, hi, axis=1)[:, 0] - at_lo) * frac  # (B, 4)
    floor = xp.minimum(xp.take(floor, xp.asarray([0, 1, 0, 1], device=device(floor)), axis=1),
                       xp.take(floor, xp.asarray([2, 3, 2, 3], device=device(floor)), axis=1))
    h = h - floor[:, None]
    speed = ts.norm(ts.gradient(feet)) * fps  # (B, T, 4)
    k = lambda v: ts.const(h, v)  # noqa: E731
    enter = (h < k(config.height_on)) & (speed < k(config.speed_on))
    stay = (h < k(config.height_off)) & (speed < k(config.speed_off))
    series = lambda x: xp.reshape(xp.permute_dims(x, (0, 2, 1)), (B * 4, T))  # noqa: E731
    c = hysteresis(series(enter), series(stay))
    c = durations_cleaned(c, max(1, round(config.min_contact * fps)), max(1, round(config.min_gap * fps)))
    return xp.permute_dims(xp.reshape(c, (B, 4, T)), (0, 2, 1))


def kinematic_contacts(joints: np.ndarray, fps: float, *, foot_joints: tuple[int, int, int, int] = HML_FOOT_JOINTS,
                       up_axis: int = 1, config: KinematicContactConfig = KinematicContactConfig()) -> np.ndarray:
    """Joints (T, J, 3) in metres at ``fps`` -> contacts (T, 4) bool for ``foot_joints`` (left ankle, left toe,
    right ankle, right toe). Needs no model or file; works for any skeleton given its foot joints and up axis."""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[-1] != 3 or len(joints) < 2:
        raise SMFError(f"expected joints of shape (T>=2, J, 3), got {tuple(joints.shape)}")
    if not fps > 0:
        raise SMFError(f"fps must be positive, got {fps}")
    return contacts_of_feet(joints[None][:, :, list(foot_joints)], fps, config, up_axis)[0]


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
