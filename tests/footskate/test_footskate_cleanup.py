"""Cleanup: skating goes down, joints move little, bones keep their lengths, features come back with the same
length, fast."""

import time
from pathlib import Path

import numpy as np
import pytest
import torch

from stablemofusion.errors import SMFError
from stablemofusion.footskate.cleanup import (CleanupConfig, align_yaw_xz, anchor_targets, cleanup_features,
                                              cleanup_joints, cleanup_rigid, features_from_cleaned, split_contact)
from stablemofusion.footskate.metrics import joint_change, skate_ratio
from stablemofusion.motion.features import bone_lengths, features_from_joints, joints_from_features
from stablemofusion.motion.rigid import bone_length_deviation, rigid_from_features

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    torch.set_num_threads(1)


UPPER_BODY = [0, 3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21]


def test_cleanup_removes_added_root_slide(wave, add_root_slide):
    """Default: the body keeps its (slid) path, the legs absorb the slide, the feet go back to where the
    clean capture planted them (up to one constant shift)."""
    slid = add_root_slide(wave)
    assert skate_ratio(slid) > 0.1 and skate_ratio(wave) == 0.0
    cleanup_joints(slid[:30], 20.0)  # the first torch.optim use in a process costs seconds of imports
    t = time.perf_counter()
    res = cleanup_joints(slid, 20.0)
    seconds = time.perf_counter() - t
    assert skate_ratio(res.joints) <= 0.02
    assert joint_change(slid[:, UPPER_BODY], res.joints[:, UPPER_BODY]) < 0.01
    toes = res.joints[:, [10, 11]] - wave[:, [10, 11]]
    assert np.linalg.norm(toes - toes.mean(0), axis=-1).mean() < 0.01
    slid_toes = slid[:, [10, 11]] - wave[:, [10, 11]]
    assert np.linalg.norm(slid_toes - slid_toes.mean(0), axis=-1).mean() > 0.03
    assert seconds < 1.0  # ~0.03 s on a 2-core CPU; generous for CI


def test_cleanup_may_move_the_body_back(wave, add_root_slide):
    """With the root path free (w_root_offset=0) the whole body goes back over its planted feet: the result
    is the clean capture up to a constant shift."""
    slid = add_root_slide(wave)
    res = cleanup_joints(slid, 20.0, CleanupConfig(w_root_offset=0.0))
    assert skate_ratio(res.joints) <= 0.02
    # (rigid legs cannot absorb what the root-velocity term keeps of the slide: 4.0 cm left of 4.9)
    assert joint_change(wave, align_yaw_xz(res.joints, wave)) < 0.045
    assert joint_change(wave, align_yaw_xz(res.joints, wave)) < joint_change(wave, align_yaw_xz(slid, wave))


def test_anchor_targets_pin_the_interval_mean_on_the_floor():
    j = np.zeros((10, 22, 3))
    j[:, 10, 0] = np.arange(10) * 0.01
    j[:, 10, 1] = 0.02
    j[:, 7, 1] = 0.1
    c = np.zeros((10, 4), bool)
    c[2:7, :2] = True
    tgt, mask = anchor_targets(j, c)
    assert mask[:, :2].sum() == 10 and not mask[:, 2:].any()
    assert np.allclose(tgt[2:7, 1], [0.04, 0.0, 0.0])  # toe at its mean over frames 2..6, on the floor
    assert np.allclose(tgt[2:7, 0], [0.0, 0.1, 0.0])  # ankle at its mean height
    tgt, _ = anchor_targets(j, c, floor=False)
    assert np.allclose(tgt[2:7, 1], [0.04, 0.02, 0.0]) and np.allclose(tgt[2:7, 0], [0.0, 0.1, 0.0])


def test_cleanup_keeps_bone_lengths(wave, add_root_slide):
    """The cleanup moves rotations and the root only: every bone keeps its length in every frame."""
    slid = add_root_slide(wave)
    res = cleanup_joints(slid, 20.0)
    before = np.median(bone_lengths(slid), 0)
    assert np.abs(bone_lengths(res.joints) - before).max() < 1e-5
    assert np.allclose(res.motion.joints(), res.joints)


def test_split_contact_and_reach():
    """A 'contact' in which the foot travels 1 m is split into pieces that stay within the allowed shift, and a
    frame whose anchor the hip cannot reach is left free."""
    pts = np.zeros((20, 3))
    pts[:, 0] = np.linspace(0.0, 1.0, 20)
    pieces = split_contact(pts, 0.15)
    assert pieces[0][0] == 0 and pieces[-1][1] == 20 and len(pieces) > 3
    assert all(b2 == a2 for (_, b2), (a2, _) in zip(pieces[:-1], pieces[1:]))
    for a, b in pieces:
        xz = pts[a:b, [0, 2]]
        assert np.linalg.norm(xz - xz.mean(0), axis=-1).max() <= 0.15
    assert split_contact(pts[:3], 0.15) == [(0, 3)]

    j = np.zeros((20, 22, 3))
    j[:, 10] = pts  # left toe slides 1 m while the hip walks 2 m away from it
    j[:, 1, 0] = np.linspace(0.0, 2.0, 20)
    j[:, 1, 1] = 0.7
    c = np.zeros((20, 4), bool)
    c[:, 1] = True
    lengths = np.full(22, 0.3)  # hip -> knee -> ankle -> toe: 0.9 m of reach
    tgt, mask = anchor_targets(j, c, max_shift=0.15, bone_lengths=lengths)
    reach = np.linalg.norm(tgt[:, 1] - j[:, 1], axis=-1) <= 0.9
    assert np.array_equal(mask[:, 1], reach) and 0 < mask[:, 1].sum() < 20
    assert not mask[:, [0, 2, 3]].any()


def test_cleanup_never_drags_a_foot_the_body_has_left():
    """The shipped model's "an elderly person walking a short distance forward" (first test captions, their
    lengths, seed 0; stored raw features): the old cleanup anchored a toe for a whole long 'contact' while the
    body walked on, stretching the leg by 40 cm. Now every bone keeps its length and no foot is dragged."""
    f = np.load(DATA / "dragged_foot_features.npy").astype(np.float64)
    body = rigid_from_features(f)
    res = cleanup_rigid(body, 20.0)
    assert bone_length_deviation(res.joints)["bone_worst"] < 1e-6
    moved = np.linalg.norm(res.joints - body.joints(), axis=-1)
    # a foot moves at most about the split distance (0.25 m); without split and reach the toe is dragged 0.6 m
    assert moved[:, [7, 8, 10, 11]].max() < 0.3
    assert moved.mean() < 0.04
    out, motion = cleanup_features(f)
    assert bone_length_deviation(joints_from_features(out))["bone_worst"] < 1e-6
    assert np.abs(joints_from_features(out) - motion.joints()).max() < 1e-9


def test_features_keep_length_and_round_trip(wave):
    f = features_from_cleaned(wave)
    assert f.shape == (len(wave), 263)
    back = align_yaw_xz(joints_from_features(f), wave)
    assert joint_change(wave, back) < 0.01
    ref = features_from_joints(wave, uniform=False)
    assert np.allclose(f[:-1], ref, atol=2e-3)  # only the smoothed facing sees the extra frame


def test_cleanup_features_and_errors(wave):
    feats = features_from_joints(np.concatenate([wave, wave[-1:]]))
    out, motion = cleanup_features(feats)
    assert out.shape == feats.shape and np.isfinite(out).all() and len(motion) == len(feats)
    with pytest.raises(SMFError, match="263"):
        cleanup_features(feats[:, :100])
    with pytest.raises(SMFError, match="vGRF model"):
        cleanup_joints(wave, config=CleanupConfig(contacts="vgrf"))
    with pytest.raises(SMFError, match="unknown contact route"):
        cleanup_joints(wave, config=CleanupConfig(contacts="magic"))


def test_cleanup_with_a_vgrf_model(wave, add_root_slide):
    from stablemofusion.footskate.vgrf import VgrfStudent

    torch.manual_seed(0)
    model = VgrfStudent().eval()
    res = cleanup_joints(add_root_slide(wave), 20.0, CleanupConfig(contacts="vgrf"), vgrf_model=model)
    assert res.joints.shape == wave.shape and np.isfinite(res.joints).all()
