"""Leaning into turns: the body tilts towards the centre of the curve its root follows, as real people do.

Measured on the corpus's walks, runs and turning walks (``benchmarks/final_stage_check.py lean``): the torso's
sideways lean (pelvis to neck, from vertical, both smoothed over :data:`SMOOTH_S`) follows
``LEAN_SHARE * atan(a_lat / g)``, where ``a_lat`` is the sideways acceleration of the root's smoothed ground path
(``v * omega`` on a curve). :func:`lean_into_turns` adds, where a motion leans less than that, the missing part:
the body above the legs turns about the pelvis (the legs are placed afterwards by the footskate cleanup).
"""

from __future__ import annotations

import numpy as np

from .features import gaussian_smooth, smoothstep
from .ik import LEG_CHAIN_JOINTS

G = 9.81  # m/s^2
LEAN_SHARE = 0.65  # measured slope of lean against atan(a_lat / g) on the corpus (least squares through 0)
SMOOTH_S = 0.5  # s: the Gaussian (standard deviation) over which the path and the lean are smoothed
MAX_LEAN_DEG = 30.0
MOVING = (0.3, 0.6)  # m/s: below the first speed nobody leans into a "turn" (a sway of a standing body), above the
# second the full lean (the corpus fit is of frames faster than 0.5 m/s); smoothstep between
NECK = 12


def smooth(x: np.ndarray, sigma: float) -> np.ndarray:
    """``x`` (T, ...) smoothed along time by a Gaussian of ``sigma`` frames reaching 3 sigmas (edges held)."""
    return gaussian_smooth(x, sigma, truncate=3.0)


def turn_frame(joints: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Of joints (T, 22, 3) metres: the unit direction of travel (T, 2) (x, z), the sideways acceleration of the
    smoothed root path (T,) m/s^2 (positive: towards the left of travel) and the speed (T,) m/s."""
    sigma = SMOOTH_S * fps
    xz = smooth(joints[:, 0, [0, 2]], sigma)
    v = np.gradient(xz, axis=0) * fps if len(xz) > 1 else np.zeros_like(xz)
    a = np.gradient(v, axis=0) * fps if len(xz) > 1 else np.zeros_like(xz)
    speed = np.linalg.norm(v, axis=-1)
    ahead = v / np.maximum(speed, 1e-6)[:, None]
    left = np.stack([ahead[:, 1], -ahead[:, 0]], -1)  # facing +Z, +X is to the left
    return ahead, np.sum(a * left, -1), speed


def sideways_lean(joints: np.ndarray, fps: float, ahead: np.ndarray | None = None) -> np.ndarray:
    """(T,) degrees: the torso's (pelvis to neck) lean towards the left of the direction of travel, frame by frame
    in the frame of travel, then smoothed (a vector smoothed in the world would lose its sideways part on a tight
    curve); ``ahead`` (T, 2) is :func:`turn_frame`'s, computed when not given."""
    if ahead is None:
        ahead, _, _ = turn_frame(joints, fps)
    left = np.stack([ahead[:, 1], -ahead[:, 0]], -1)
    up = joints[:, NECK] - joints[:, 0]
    return smooth(np.degrees(np.arctan2(np.sum(up[:, [0, 2]] * left, -1), up[:, 1])), SMOOTH_S * fps)


def expected_lean(joints: np.ndarray, fps: float, share: float = LEAN_SHARE) -> np.ndarray:
    """(T,) degrees: the lean real people show for this path, ``share * atan(a_lat / g)`` (positive: left), faded
    out below walking speed (:data:`MOVING`)."""
    _, a_lat, speed = turn_frame(joints, fps)
    return _lean_for(a_lat, speed, share)


def _lean_for(a_lat: np.ndarray, speed: np.ndarray, share: float) -> np.ndarray:
    moving = smoothstep((speed - MOVING[0]) / (MOVING[1] - MOVING[0]))
    return np.clip(share * np.degrees(np.arctan(a_lat / G)), -MAX_LEAN_DEG, MAX_LEAN_DEG) * moving


def lean_into_turns(joints: np.ndarray, fps: float, share: float = LEAN_SHARE) -> np.ndarray:
    """Joints (T, 22, 3) metres with the body above the legs turned about the pelvis, about the direction of
    travel, by what it lacks of :func:`expected_lean` (a motion already leaning enough is left as it is). Rigid:
    every joint but the legs' turns with the pelvis; the legs are placed by the cleanup's IK."""
    x = np.asarray(joints, dtype=np.float64)
    if share <= 0 or len(x) < 3:
        return x.copy()
    ahead, a_lat, speed = turn_frame(x, fps)
    want = _lean_for(a_lat, speed, share)
    have = sideways_lean(x, fps, ahead)
    extra = np.sign(want) * np.maximum(np.abs(want) - np.sign(want) * have, 0.0)
    if not np.any(np.abs(extra) > 1e-3):
        return x.copy()
    theta = np.radians(extra)
    # rotation about the axis of travel a = (ax, 0, az); positive theta tips +Y towards the left (az, 0, -ax)
    ax, az = ahead[:, 0], ahead[:, 1]
    c, s = np.cos(theta), np.sin(theta)
    body = [j for j in range(x.shape[1]) if j not in LEG_CHAIN_JOINTS]
    rel = x[:, body] - x[:, :1]
    along = rel[..., 0] * ax[:, None] + rel[..., 2] * az[:, None]  # component along the axis
    lat = rel[..., 0] * az[:, None] - rel[..., 2] * ax[:, None]  # towards the left
    up = rel[..., 1]
    lat2 = c[:, None] * lat + s[:, None] * up
    up2 = -s[:, None] * lat + c[:, None] * up
    out = x.copy()
    out[:, body, 0] = x[:, :1, 0] + along * ax[:, None] + lat2 * az[:, None]
    out[:, body, 2] = x[:, :1, 2] + along * az[:, None] - lat2 * ax[:, None]
    out[:, body, 1] = x[:, :1, 1] + up2
    return out


__all__ = ["LEAN_SHARE", "expected_lean", "lean_into_turns", "sideways_lean", "turn_frame"]
