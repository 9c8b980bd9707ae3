"""Two-bone IK of the legs: targets reached within reach, bone lengths kept, the knee's side kept, a leg at its target
unchanged; the pelvis moved smoothly only where a leg falls short."""

import numpy as np

from stablemofusion.motion.files import load_motion
from stablemofusion.motion.ik import LEGS, place_legs, reach_shift, two_bone
from stablemofusion.motion.rigid import fit_rigid


def test_two_bone_reaches_its_target_with_the_knee_on_its_side():
    rng = np.random.default_rng(0)
    hip = rng.normal(size=(50, 3))
    knee = hip + np.array([0.0, -0.4, 0.1])
    target = hip + rng.normal(size=(50, 3)) * 0.2 + np.array([0.0, -0.5, 0.0])
    k, a = two_bone(hip, knee, target, 0.42, 0.40)
    reachable = np.linalg.norm(target - hip, axis=-1) < 0.999 * 0.82
    assert np.abs(a - target)[reachable].max() < 1e-9
    assert np.allclose(np.linalg.norm(k - hip, axis=-1), 0.42) and np.allclose(np.linalg.norm(a - k, axis=-1), 0.40)
    axis = (a - hip) / np.linalg.norm(a - hip, axis=-1, keepdims=True)
    side = lambda p: (p - hip) - axis * np.sum((p - hip) * axis, -1, keepdims=True)  # noqa: E731
    assert np.all(np.sum(side(k) * side(knee), -1) > 0)  # bent the way the input knee was


def test_legs_at_their_targets_stay_and_moved_feet_keep_every_bone():
    body = fit_rigid(load_motion("example:wave-both-hands").joints.astype(np.float64))
    x, lengths = body.joints(), body.bone_lengths
    same = place_legs(x, x[:, [7, 8]], x[:, [10, 11]], lengths)
    assert np.abs(same - x).max() < 1e-9
    moved = place_legs(x, x[:, [7, 8]] + [0.05, 0.03, 0.04], x[:, [10, 11]] + [0.05, 0.0, 0.04], lengths)
    for leg in LEGS:
        for parent, child in zip(leg[:-1], leg[1:]):
            assert np.allclose(np.linalg.norm(moved[:, child] - moved[:, parent], axis=-1), lengths[child])
    assert np.abs(moved[:, [7, 8]] - (x[:, [7, 8]] + [0.05, 0.03, 0.04])).max() < 0.02


def test_the_pelvis_moves_only_where_a_leg_falls_short_and_smoothly():
    body = fit_rigid(load_motion("example:wave-both-hands").joints.astype(np.float64))
    x, lengths = body.joints(), body.bone_lengths
    assert not reach_shift(x, x[:, [7, 8]], lengths, 20.0).any()
    far = x[:, [7, 8]].copy()
    far[50:60, 0, 2] += 0.3  # the left ankle asked 30 cm forward for half a second
    move = reach_shift(x, far, lengths, 20.0)
    assert np.abs(move[:40]).max() == 0 and np.linalg.norm(move[50:60], axis=-1).min() > 0.01
    assert np.linalg.norm(np.diff(move, axis=0), axis=-1).max() < 0.1  # spread over frames, never one jump
