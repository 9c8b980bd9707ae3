"""Cleanup: skating goes down, joints move little, features come back with the same length, fast."""

import time

import numpy as np
import pytest
import torch

from stablemofusion.errors import SMFError
from stablemofusion.footskate.cleanup import (CleanupConfig, align_yaw_xz, anchor_targets, cleanup_features,
                                              cleanup_joints, edit_features, features_from_cleaned)
from stablemofusion.footskate.metrics import joint_change, skate_ratio
from stablemofusion.motion.features import features_from_joints, joints_from_features


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
    assert joint_change(wave, align_yaw_xz(res.joints, wave)) < 0.03
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


def test_edit_features_keeps_untouched_dimensions(wave):
    """Features that a model made (rotations not equal to inverse kinematics of its positions) survive an
    edit wherever the edit changes nothing; the edited features decode to the edited joints."""
    feats = features_from_joints(np.concatenate([wave, wave[-1:]]))
    rng = np.random.default_rng(0)
    feats[:, 67:193] += rng.normal(0, 0.05, feats[:, 67:193].shape)  # rotations inconsistent with positions
    joints = joints_from_features(feats)
    assert np.allclose(edit_features(feats, joints, joints), feats)
    moved = joints.copy()
    moved[60:, 10, 0] += 0.05  # slide the left toe 5 cm from frame 60 on
    out = edit_features(feats, joints, moved)
    assert np.allclose(out[:50, :193], feats[:50, :193], atol=1e-6)
    back = joints_from_features(out)
    assert np.abs(back - moved).max() < 2e-3
    assert np.abs(out[:, 67:193] - feats[:, 67:193]).max() > 0.01  # rotations follow the edit


def test_features_keep_length_and_round_trip(wave):
    f = features_from_cleaned(wave)
    assert f.shape == (len(wave), 263)
    back = align_yaw_xz(joints_from_features(f), wave)
    assert joint_change(wave, back) < 0.01
    ref = features_from_joints(wave, uniform=False)
    assert np.allclose(f[:-1], ref, atol=2e-3)  # only the smoothed facing sees the extra frame


def test_cleanup_features_and_errors(wave):
    feats = features_from_joints(np.concatenate([wave, wave[-1:]]))
    out = cleanup_features(feats)
    assert out.shape == feats.shape and np.isfinite(out).all()
    with pytest.raises(SMFError, match="263"):
        cleanup_features(feats[:, :100])
    with pytest.raises(SMFError, match="vGRF model"):
        cleanup_joints(wave, config=CleanupConfig(contacts="vgrf"))
    with pytest.raises(SMFError, match="unknown contact route"):
        cleanup_joints(wave, config=CleanupConfig(contacts="magic"))


def test_cleanup_with_a_vgrf_model(wave, add_root_slide):
    from stablemofusion.footskate.distil import VgrfStudent

    torch.manual_seed(0)
    model = VgrfStudent().eval()
    res = cleanup_joints(add_root_slide(wave), 20.0, CleanupConfig(contacts="vgrf"), vgrf_model=model)
    assert res.joints.shape == wave.shape and np.isfinite(res.joints).all()
