"""Leaning into turns: a body running a circle leans in by the corpus's relation, a straight walk and a standing
sway are left as they are, and the lean is rigid (every bone keeps its length; the legs are the cleanup's IK's)."""

import numpy as np

from stablemofusion.motion.files import load_motion
from stablemofusion.motion.lean import LEAN_SHARE, SMOOTH_S, expected_lean, lean_into_turns, sideways_lean
from stablemofusion.motion.features import bone_lengths

FPS = 20.0


def _carried(pose: np.ndarray, path: np.ndarray) -> np.ndarray:
    """The standing pose (J, 3) carried along ``path`` (T, 2), facing where it goes."""
    d = np.gradient(path, axis=0)
    yaw = np.arctan2(d[:, 0], d[:, 1])
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    rel = pose - pose[:1] * [1, 0, 1]
    out = np.empty((len(path),) + pose.shape)
    out[..., 0] = c * rel[:, 0] + s * rel[:, 2] + path[:, :1]
    out[..., 2] = -s * rel[:, 0] + c * rel[:, 2] + path[:, 1:]
    out[..., 1] = rel[:, 1]
    return out


def test_a_circling_runner_leans_in_and_a_straight_walker_does_not():
    pose = load_motion("example:wave-both-hands").joints[0].astype(np.float64)
    t = np.arange(120) / FPS
    w = 2.5 / 1.5  # 2.5 m/s on a 1.5 m circle, counter-clockwise seen from above: the centre to the left
    circle = _carried(pose, np.stack([1.5 - 1.5 * np.cos(w * t), 1.5 * np.sin(w * t)], -1))
    leaned = lean_into_turns(circle, FPS)
    mid = slice(40, 80)
    # the relation is of the path smoothed over SMOOTH_S (as on the corpus): a circle smoothed by a Gaussian of sigma
    # seconds shrinks by exp(-(w sigma)^2 / 2), and so does its sideways acceleration v w
    want = LEAN_SHARE * np.degrees(np.arctan(2.5 * w * np.exp(-(w * SMOOTH_S) ** 2 / 2) / 9.81))
    assert abs(np.median(sideways_lean(circle, FPS)[mid])) < 2.0  # the standing pose's own slight lean
    assert abs(np.median(expected_lean(circle, FPS)[mid]) - want) < 0.3 and want > 10  # left, the way it turns
    assert abs(np.median(sideways_lean(leaned, FPS)[mid]) - np.median(expected_lean(circle, FPS)[mid])) < 1.0
    body = [j for j in range(22) if j not in (4, 5)]  # every bone but hip-knee: the legs are placed afterwards by IK
    assert np.abs(bone_lengths(leaned)[:, body] - bone_lengths(circle)[:, body]).max() < 1e-9
    straight = _carried(pose, np.stack([np.zeros_like(t), 1.3 * t], -1))
    assert np.abs(lean_into_turns(straight, FPS) - straight).max() < 1e-9


def test_a_standing_sway_is_not_a_turn():
    wave = load_motion("example:wave-both-hands").joints.astype(np.float64)
    t = np.arange(len(wave)) / FPS
    swayed = wave + (0.06 * np.sin(2 * np.pi * 1.3 * t))[:, None, None] * np.array([1.0, 0.0, 0.0])
    assert np.abs(lean_into_turns(swayed, FPS) - swayed).max() < 1e-9
