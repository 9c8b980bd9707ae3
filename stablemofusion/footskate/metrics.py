"""Foot-skating metrics on joint positions (T, 22, 3), metres, Y up, floor at y = 0 (HumanML3D's
convention: canonicalisation puts the lowest joint of a motion at y = 0, and the toes of a real standing
pose sit within a few millimetres of it).

Thresholds are per frame at 20 fps, as in the literature (GMD, PhysDiff); other rates are resampled to
20 fps first so figures are comparable.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import SMFError
from ..motion.resample import resample

TOES = (10, 11)  # HumanML3D left/right toe ("foot") joints
METRIC_FPS = 20.0


def _check(joints: np.ndarray) -> np.ndarray:
    j = np.asarray(joints, dtype=np.float64)
    if j.ndim != 3 or j.shape[1:] != (22, 3) or len(j) < 2:
        raise SMFError(f"expected joints of shape (T>=2, 22, 3), got {tuple(j.shape)}")
    return j


def skating_frames(joints: np.ndarray, *, height: float = 0.05, slide: float = 0.025) -> np.ndarray:
    """(T, 22, 3) at 20 fps -> (T-1, 2) bool: the toe is within ``height`` m of the floor on both frames of a
    pair and moves more than ``slide`` m horizontally between them."""
    j = _check(joints)
    toes = j[:, list(TOES)]
    low = (toes[1:, :, 1] <= height) & (toes[:-1, :, 1] <= height)
    step = np.linalg.norm(toes[1:, :, [0, 2]] - toes[:-1, :, [0, 2]], axis=-1)
    return low & (step > slide)


def skate_ratio(joints: np.ndarray, *, height: float = 0.05, slide: float = 0.025) -> float:
    """Fraction of frame pairs (20 fps) in which either foot skates (see :func:`skating_frames`)."""
    return float(skating_frames(joints, height=height, slide=slide).any(-1).mean())


def sliding_speed(joints: np.ndarray, fps: float = METRIC_FPS, *, height: float = 0.05) -> float:
    """Mean horizontal toe speed (m/s) over the frame pairs in which the toe stays within ``height`` m of
    the floor (0 when it never does)."""
    j = _check(joints)
    toes = j[:, list(TOES)]
    low = (toes[1:, :, 1] <= height) & (toes[:-1, :, 1] <= height)
    speed = np.linalg.norm(toes[1:, :, [0, 2]] - toes[:-1, :, [0, 2]], axis=-1) * fps
    return float(speed[low].mean()) if low.any() else 0.0


def penetration(joints: np.ndarray) -> float:
    """Mean over frames of the depth (m) of the lowest joint below the floor (0 where none is below)."""
    j = _check(joints)
    return float(np.maximum(0.0, -j[..., 1].min(-1)).mean())


def joint_change(before: np.ndarray, after: np.ndarray) -> float:
    """Mean Euclidean distance (m) between corresponding joints of two (T, J, 3) motions."""
    a, b = np.asarray(before, np.float64), np.asarray(after, np.float64)
    if a.shape != b.shape:
        raise SMFError(f"joint arrays differ in shape: {a.shape} vs {b.shape}")
    return float(np.linalg.norm(a - b, axis=-1).mean())


def pose_change(before: np.ndarray, after: np.ndarray) -> float:
    """Mean distance (m) between corresponding joints once each frame's root is moved to the origin: the
    part of :func:`joint_change` that is not a change of the global path."""
    a, b = np.asarray(before, np.float64), np.asarray(after, np.float64)
    if a.shape != b.shape:
        raise SMFError(f"joint arrays differ in shape: {a.shape} vs {b.shape}")
    return float(np.linalg.norm((a - a[:, :1]) - (b - b[:, :1]), axis=-1).mean())


def footskate_metrics(joints: np.ndarray, fps: float = METRIC_FPS) -> dict[str, float]:
    """All metrics of one motion (T, 22, 3) at ``fps``: skate_ratio, slide_speed (m/s), penetration (m)."""
    j = _check(joints)
    j = resample(j, fps, METRIC_FPS) if abs(fps - METRIC_FPS) > 1e-9 else j
    return {"skate_ratio": skate_ratio(j), "slide_speed": sliding_speed(j), "penetration": penetration(j)}


def mean_metrics(motions: list[np.ndarray], fps: float = METRIC_FPS) -> dict[str, float]:
    """Average :func:`footskate_metrics` over motions (each weighted equally)."""
    if not motions:
        raise SMFError("no motions to measure")
    rows = [footskate_metrics(m, fps) for m in motions]
    return {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}


FOOT_JOINTS = (7, 10, 8, 11)  # HumanML3D left ankle, left toe, right ankle, right toe


def _foot_steps(j: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Of joints (T, 22, 3) at 20 fps, per frame pair and foot joint (T-1, 4): low (within ``height`` m of the floor
    on both frames), the horizontal step (m) and the step of the pair before (inf for the first)."""
    feet = j[:, list(FOOT_JOINTS)]
    low = (feet[1:, :, 1] <= height) & (feet[:-1, :, 1] <= height)
    step = np.linalg.norm(feet[1:, :, [0, 2]] - feet[:-1, :, [0, 2]], axis=-1)
    before = np.concatenate([np.full((1, 4), np.inf), step[:-1]], 0)
    return low, step, before


def pop_frames(joints: np.ndarray, *, height: float = 0.06, jump: float = 0.15, still: float = 0.03) -> np.ndarray:
    """(T, 22, 3) at 20 fps -> (T-1, 4) bool: a foot joint (ankle or toe) that teleports: within ``height`` m of
    the floor on both frames of a pair, it moves more than ``jump`` m horizontally between them, having moved
    less than ``still`` m horizontally in the pair before (a planted foot that jumps). Real mocap has none
    (0 of the corpus's 3,119 clips); one such frame is one skating frame to :func:`skate_ratio`, which cannot
    see it."""
    low, step, before = _foot_steps(_check(joints), height)
    return low & (step > jump) & (before < still)


def steps_after_stillness(joints: np.ndarray, *, height: float = 0.06, still: float = 0.03) -> np.ndarray:
    """(n,) the horizontal steps (m, 20 fps) of foot joints low on both frames, taken right after a step of less
    than ``still`` m: how fast a planted foot leaves its place (real feet: 7.8 cm at most on the test clips)."""
    low, step, before = _foot_steps(_check(joints), height)
    return step[low & (before < still)]


def pop_count(joints: np.ndarray, fps: float = METRIC_FPS) -> int:
    """Frames in which any foot joint teleports (:func:`pop_frames`; other frame rates are resampled to 20 fps)."""
    j = _check(joints)
    j = resample(j, fps, METRIC_FPS) if abs(fps - METRIC_FPS) > 1e-9 else j
    return int(pop_frames(j).any(-1).sum())
