import numpy as np
import pytest
import torch

from stablemofusion.core.errors import MotionFormatError
from stablemofusion.motion.features import (
                                            bone_lengths, canonicalize, feature_slices, features_from_joints, joints_from_features, mirror_features,
                                            mirror_joints,
                                            )
from stablemofusion.motion.skeleton import HUMANML3D, KIT


def test_joints_from_reference_features_match_reference_joints(ref_motion):
    _, joints, feats = ref_motion
    rec = joints_from_features(feats)
    assert rec.shape == joints.shape
    assert np.abs(rec - joints).max() < 1e-4


def test_torch_batched_matches_numpy(ref_motion):
    _, joints, feats = ref_motion
    batch = torch.from_numpy(np.stack([feats[:100], feats[:100]])).float()
    rec = joints_from_features(batch)
    assert rec.shape == (2, 100, 22, 3) and rec.dtype == torch.float32
    assert np.abs(rec[1].numpy() - joints[:100]).max() < 1e-4


def test_round_trip_within_a_millimetre(ref_motion):
    _, joints, _ = ref_motion
    feats = features_from_joints(joints)
    assert feats.shape == (len(joints) - 1, 263)
    back = joints_from_features(feats)
    assert np.abs(back - canonicalize(joints)[:-1]).max() < 1e-3


def test_round_trip_of_a_motion_that_turns_one_and_a_half_times(ref_motion):
    """The facing passes 180 degrees (its quaternion changes sign) three times: the yaw channel must keep the
    turn's direction there, or the decoded root path turns the wrong way from that frame on."""
    _, joints, _ = ref_motion
    theta = np.linspace(0.0, 3 * np.pi, len(joints))[:, None]
    rel = joints - joints[:, :1] * np.array([1.0, 0.0, 1.0])
    spun = rel.copy()
    spun[..., 0] = np.cos(theta) * rel[..., 0] + np.sin(theta) * rel[..., 2]
    spun[..., 2] = -np.sin(theta) * rel[..., 0] + np.cos(theta) * rel[..., 2]
    spun += joints[:, :1] * np.array([1.0, 0.0, 1.0])
    back = joints_from_features(features_from_joints(spun))
    assert np.abs(back - canonicalize(spun)[:-1]).max() < 1e-3


def test_recomputed_features_agree_with_reference_by_group(ref_motion):
    # Tolerances documented in docs/motion-representation.md; the reference was computed from one more
    # frame of raw data, which moves the smoothed facing direction a little near the clip's end.
    _, joints, ref = ref_motion
    feats = features_from_joints(joints)
    tol = {"root_yaw_velocity": 1e-3, "root_xz_velocity": 1e-3, "root_height": 1e-6, "positions": 1e-2,
           "rotations": 2e-2, "velocities": 1e-3, "contacts": 0.0}
    for name, sl in feature_slices().items():
        assert np.abs(feats[:, sl] - ref[:-1, sl]).max() <= tol[name], name


def test_canonical_frame(ref_motion):
    _, joints, _ = ref_motion
    # move and turn the motion; canonicalisation must undo it
    angle = 1.1
    rot = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    moved = joints @ rot.T + np.array([3.0, 0.5, -2.0])
    feats_moved = features_from_joints(moved)
    assert np.abs(feats_moved - features_from_joints(joints)).max() < 1e-6
    canon = canonicalize(moved)
    assert abs(canon[..., 1].min()) < 1e-9
    assert np.allclose(canon[0, 0, [0, 2]], 0.0)
    # left hip (+X) when facing +Z
    assert canon[0, 1, 0] > canon[0, 2, 0]


def test_uniform_skeleton_gives_target_bone_lengths(ref_motion):
    _, joints, _ = ref_motion
    scaled = joints * 1.3
    canon = canonicalize(scaled)
    lengths = bone_lengths(canon)
    assert np.abs(lengths - np.array(HUMANML3D.bone_lengths)).max() < 1e-6


def test_mirror_features_equals_features_of_mirrored_joints(ref_motion):
    _, joints, _ = ref_motion
    f = features_from_joints(joints, uniform=False)
    assert np.abs(mirror_features(f) - features_from_joints(mirror_joints(joints), uniform=False)).max() < 1e-9
    assert np.abs(mirror_features(mirror_features(f)) - f).max() == 0
    ft = torch.from_numpy(f)
    assert torch.allclose(mirror_features(ft), torch.from_numpy(mirror_features(f)))


def test_mirror_swaps_sides():
    joints = np.zeros((2, 22, 3))
    joints[:, 1, 0] = 0.1  # left hip at +X
    m = mirror_joints(joints)
    assert m[0, 2, 0] == -0.1 and m[0, 1, 0] == 0.0


def test_kit_shapes_round_trip():
    rng = np.random.default_rng(0)
    # a KIT-like skeleton built from the raw offsets, random smooth motion (millimetres)
    T = 30
    offs = KIT.offsets_array * 200.0
    joints = np.zeros((T, 21, 3))
    root = np.cumsum(rng.normal(0, 5, (T, 3)), 0) + np.array([0, 1000.0, 0])
    joints[:, 0] = root
    for j, p in enumerate(KIT.parents):
        if p >= 0:
            joints[:, j] = joints[:, p] + offs[j] + rng.normal(0, 10, (T, 3))
    feats = features_from_joints(joints, "kit")
    assert feats.shape == (T - 1, 251)
    back = joints_from_features(feats, "kit")
    assert np.abs(back - canonicalize(joints, "kit")[:-1]).max() < 1e-6


@pytest.mark.parametrize("bad, msg", [
    (np.zeros((10, 21, 3)), "shape"),
    (np.zeros((1, 22, 3)), "at least 2 frames"),
    (np.full((5, 22, 3), np.nan), "NaN"),
])
def test_bad_joints(bad, msg):
    with pytest.raises(MotionFormatError, match=msg):
        features_from_joints(bad)


def test_bad_features():
    with pytest.raises(MotionFormatError, match="263"):
        joints_from_features(np.zeros((10, 200)))
    with pytest.raises(MotionFormatError, match="NaN"):
        joints_from_features(np.full((3, 263), np.inf))
