"""Cleanup: skating goes down, planted feet never jump, joints move little, bones keep their lengths, features come
back with the same length."""

from pathlib import Path

import numpy as np
import pytest
import torch

from stablemofusion.core.errors import SMFError
from stablemofusion.footskate.cleanup import (CleanupConfig, align_yaw_xz, bridge, cleanup_features, cleanup_joints,
                                              cleanup_rigid, features_from_cleaned, hold_places, holds)
from stablemofusion.footskate.metrics import joint_change, pop_frames, skate_ratio
from stablemofusion.motion.features import bone_lengths, features_from_joints, joints_from_features
from stablemofusion.motion.rigid import bone_length_deviation, rigid_from_features

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    torch.set_num_threads(1)


UPPER_BODY = [0, 3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21]


def test_cleanup_removes_added_root_slide(wave, add_root_slide):
    """The body keeps its (slid) path, the legs absorb the slide, the feet stay where they stood."""
    slid = add_root_slide(wave)
    assert skate_ratio(slid) > 0.1 and skate_ratio(wave) == 0.0
    res = cleanup_joints(slid, 20.0)
    assert skate_ratio(res.joints) <= 0.02
    assert joint_change(slid[:, UPPER_BODY], res.joints[:, UPPER_BODY]) < 0.01
    toes = res.joints[:, [10, 11]] - wave[:, [10, 11]]
    assert np.linalg.norm(toes - toes.mean(0), axis=-1).mean() < 0.01
    slid_toes = slid[:, [10, 11]] - wave[:, [10, 11]]
    assert np.linalg.norm(slid_toes - slid_toes.mean(0), axis=-1).mean() > 0.03


def test_holds_pin_the_mean_and_cut_long_glides_with_room_to_move():
    pts = np.zeros((30, 4, 3))
    pts[:, 1, 0] = np.linspace(0.0, 1.0, 30)  # a toe gliding 1 m while "planted"
    c = np.zeros((30, 4), bool)
    c[:, 1] = True
    c[5:10, 0] = True
    place, held = holds(pts, c, 0.15, 2)
    assert held[5:10, 0].all() and not held[:5, 0].any() and np.allclose(place[5:10, 0], 0.0)
    free = np.flatnonzero(~held[:, 1])
    assert len(free) >= 4  # each cut leaves 2 + 2 frames for the foot to travel to its next hold
    for a in range(30):
        if held[a, 1]:
            assert abs(place[a, 1, 0] - pts[a, 1, 0]) <= 0.15 + 1e-9


def test_bridge_eases_between_holds_and_holds_at_the_ends():
    off = np.zeros((10, 1))
    off[:3] = 1.0
    off[7:] = 3.0
    held = np.zeros(10, bool)
    held[:3] = held[7:] = True
    out = bridge(off, held)[:, 0]
    assert np.allclose(out[:3], 1.0) and np.allclose(out[7:], 3.0)
    assert np.all(np.diff(out) >= 0) and np.allclose(out[3] + out[6], 4.0)  # smoothstep: symmetric about the middle
    assert np.allclose(bridge(off, np.zeros(10, bool)), 0.0)


def test_the_cleanup_never_makes_a_planted_foot_jump(wave):
    """A foot that the motion drags along the floor in its contacts (a glide of 0.8 m): the cleanup holds it and
    carries it to its next hold over several frames, never in one."""
    glide = wave.copy()
    glide[:, [7, 10], 0] += np.linspace(0.0, 0.8, len(wave))[:, None]
    res = cleanup_joints(glide, 20.0)
    assert not pop_frames(res.joints).any()
    toe = np.linalg.norm(np.diff(res.joints[:, 10, [0, 2]], axis=0), axis=-1)
    assert np.mean(toe < 0.005) > 0.6 and np.mean(np.diff(glide[:, 10, [0, 2]], axis=0)[:, 0] < 0.005) == 0.0


def test_cleanup_keeps_bone_lengths(wave, add_root_slide):
    """The cleanup moves rotations and the root only: every bone keeps its length in every frame."""
    slid = add_root_slide(wave)
    res = cleanup_joints(slid, 20.0)
    before = np.median(bone_lengths(slid), 0)
    assert np.abs(bone_lengths(res.joints) - before).max() < 1e-5
    assert np.allclose(res.motion.joints(), res.joints)


def test_hold_places_cut_a_glide_into_pieces_and_never_a_still_foot():
    """A 'contact' in which the foot travels 1 m is cut into pieces, each held within the allowed shift of where
    the foot was, with free frames between; a planted foot that jitters by 2 cm is held in one piece."""
    pts = np.zeros((1, 20, 3))
    pts[0, :, 0] = np.linspace(0.0, 1.0, 20)
    place, held = hold_places(pts, np.ones((1, 20), bool), 0.15, 1)
    holds_at = np.unique(place[0, held[0], 0])
    assert len(holds_at) > 3 and (~held[0]).sum() >= 2 * (len(holds_at) - 1)
    assert np.abs(place[0, held[0]] - pts[0, held[0]]).max() <= 0.15
    still = np.random.default_rng(0).uniform(-0.02, 0.02, (1, 40, 3))
    place, held = hold_places(still, np.ones((1, 40), bool), 0.15, 3)
    assert held.all() and np.allclose(place, still.mean(1))


def test_cleanup_never_drags_a_foot_the_body_has_left():
    """The shipped model's "an elderly person walking a short distance forward" (first test captions, their
    lengths, seed 0; stored raw features): the old cleanup anchored a toe for a whole long 'contact' while the
    body walked on, stretching the leg by 40 cm. Now every bone keeps its length and no foot is dragged."""
    f = np.load(DATA / "dragged_foot_features.npy").astype(np.float64)
    body = rigid_from_features(f)
    res = cleanup_rigid(body, 20.0)
    assert bone_length_deviation(res.joints)["bone_worst"] < 1e-6
    moved = np.linalg.norm(res.joints - body.joints(), axis=-1)
    # a foot moves at most about the split distance; the old anchors dragged the toe 0.6 m
    assert moved[:, [7, 8, 10, 11]].max() < 0.3
    assert not pop_frames(res.joints).any()
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
