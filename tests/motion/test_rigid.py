"""The rigid body: forward kinematics, the closed-form pose, the fit, features written in a model's frames."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from stablemofusion.core.errors import MotionFormatError, SMFError
from stablemofusion.motion.features import (bone_lengths, features_from_joints, features_in_frames_of,
                                            joints_from_features, joints_from_rotations)
from stablemofusion.motion.files import bvh_round_trip_error, load_motion, save_rigid_bvh
from stablemofusion.motion.rigid import (RigidFitConfig, RigidMotion, bone_length_deviation, choose_bone_lengths,
                                         fit_rigid, forward_kinematics, pose_from_joints, rigid_from_features,
                                         rigid_to_features)
from stablemofusion.motion.skeleton import HUMANML3D

TARGET = np.asarray(HUMANML3D.bone_lengths)
FOREARMS = (20, 21)


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    torch.set_num_threads(1)


@pytest.fixture(scope="module")
def wave() -> np.ndarray:
    """A real capture on the dataset skeleton (118, 22, 3)."""
    return load_motion("example:wave-both-hands").joints


@pytest.fixture(scope="module")
def wave_features(wave) -> np.ndarray:
    return features_from_joints(np.concatenate([wave, wave[-1:]]))


def stretch(joints: np.ndarray, amount: float = 0.15, frames: slice = slice(10, 40)) -> np.ndarray:
    """Lengthen both forearms by ``amount`` metres in ``frames`` (the wrists move along the forearm)."""
    out = joints.copy()
    for w, e in ((20, 18), (21, 19)):
        d = out[frames, w] - out[frames, e]
        out[frames, w] += d / np.linalg.norm(d, axis=-1, keepdims=True) * amount
    return out


def test_forward_kinematics_of_the_closed_form_pose_is_exact_for_a_rigid_motion(wave):
    offsets, rotations = pose_from_joints(wave, lengths=TARGET)
    assert np.allclose(np.linalg.norm(offsets, axis=-1), TARGET)
    assert np.allclose(rotations @ np.swapaxes(rotations, -1, -2), np.eye(3), atol=1e-9)
    x = forward_kinematics(torch.from_numpy(offsets), torch.from_numpy(rotations), torch.from_numpy(wave[:, 0]),
                           HUMANML3D.parents).numpy()
    assert np.abs(x - wave).max() < 1e-4  # the example is stored in float32


def test_fit_reproduces_a_real_motion(wave):
    m = fit_rigid(wave)
    assert np.allclose(m.bone_lengths, TARGET)
    assert np.abs(m.joints() - wave).max() < 1e-3


def test_fit_makes_a_stretched_motion_rigid_and_spreads_the_error(wave):
    bad = stretch(wave)
    assert bone_length_deviation(bad)["bone_worst"] > 0.14
    closed = fit_rigid(bad, config=RigidFitConfig(iterations=0, start="positions"))
    fitted = fit_rigid(bad, config=RigidFitConfig(start="positions"))
    for m in (closed, fitted):
        lengths = bone_lengths(m.joints())[:, 1:]
        assert np.abs(lengths - TARGET[1:]).max() < 1e-6  # every bone, every frame
    err = lambda m: np.linalg.norm(m.joints() - bad, axis=-1)  # noqa: E731
    # the fit moves the arms and upper body a little to meet the stretched wrists part of the way
    assert (err(fitted) ** 2).mean() < 0.8 * (err(closed) ** 2).mean()
    assert err(fitted).max() < err(closed).max() - 0.01
    assert np.abs(fitted.joints()[:10] - wave[:10]).max() < 2e-3  # untouched frames stay


def test_bone_length_choices(wave):
    bad = stretch(wave, frames=slice(0, 100))  # forearms long in most frames: the median is long too
    assert np.allclose(choose_bone_lengths(bad, "humanml3d", "dataset"), TARGET)
    med = choose_bone_lengths(bad, "humanml3d", "median")
    assert np.allclose(med[list(FOREARMS)], TARGET[list(FOREARMS)] + 0.15, atol=1e-6)
    assert np.allclose(np.delete(med, FOREARMS), np.delete(TARGET, FOREARMS), atol=1e-6)
    with pytest.raises(SMFError, match="bone lengths must be one of"):
        choose_bone_lengths(bad, "humanml3d", "mean")
    with pytest.raises(SMFError, match="start must be one of"):
        RigidFitConfig(start="nowhere")
    with pytest.raises(SMFError, match="expected joints of shape"):
        fit_rigid(bad[..., :2])


def test_bvh_of_a_rigid_motion_reads_back_to_its_joints(wave, tmp_path):
    m = fit_rigid(stretch(wave))
    save_rigid_bvh(m, tmp_path / "m.bvh", 20.0)
    back = load_motion(tmp_path / "m.bvh").joints
    assert np.abs(back - m.joints()).max() < 1e-5
    assert bvh_round_trip_error(m.joints(), m) < 1e-4
    # the closed-form BVH of non-rigid joints cannot hold them: the case the rigid stage removes
    assert bvh_round_trip_error(stretch(wave)) > 0.05


def test_joints_from_rotations_is_exact_for_real_features(wave_features):
    assert np.abs(joints_from_rotations(wave_features) - joints_from_features(wave_features)).max() < 1e-6


def test_features_in_frames_of_round_trips_real_features(wave_features):
    joints = joints_from_features(wave_features)
    out = features_in_frames_of(joints, wave_features)
    assert np.abs(out[:-1] - wave_features[:-1]).max() < 1e-6  # the last velocity is extrapolated
    assert np.array_equal(out[:, -4:], wave_features[:, -4:])  # contacts kept


def test_features_in_frames_of_decode_exactly_and_keep_the_frames(wave_features):
    """Features a model made (rotations inconsistent with positions, a yaw of its own) take new joints: they
    decode to them exactly, keep their yaw channel, and keep or recompute their rotations."""
    rng = np.random.default_rng(0)
    f = wave_features.copy()
    f[:, 67:193] += rng.normal(0, 0.05, f[:, 67:193].shape)
    f[:, 0] += 0.01
    moved = stretch(joints_from_features(f))
    for rotations in ("ik", "keep"):
        out = features_in_frames_of(moved, f, rotations=rotations)
        assert np.abs(joints_from_features(out) - moved).max() < 1e-9
        assert np.array_equal(out[:, 0], f[:, 0])
    assert np.array_equal(features_in_frames_of(moved, f, rotations="keep")[:, 67:193], f[:, 67:193])
    ik = features_in_frames_of(moved, f, rotations="ik")
    assert np.abs(joints_from_rotations(ik, lengths=bone_lengths(moved)[12]) - moved)[12].max() < 1e-6
    with pytest.raises(MotionFormatError, match="frames of joints"):
        features_in_frames_of(moved[:-1], f)


def test_rigid_from_features_and_back(wave_features):
    """The pipeline's final stage on a model-like output: rigid, starting from the rotation channels, and the
    features written back decode to the rigid joints exactly."""
    f = wave_features.copy()
    j = stretch(joints_from_features(f))
    f = features_in_frames_of(j, f, rotations="keep")  # positions stretched, rotations still the capture's
    for start in ("rotations", "positions"):
        m = rigid_from_features(f, config=RigidFitConfig(start=start))
        moved, out = rigid_to_features(m, f)
        assert np.allclose(moved.root[0, [0, 2]], 0.0)
        assert np.abs(joints_from_features(out) - moved.joints()).max() < 1e-9
        assert bone_length_deviation(moved.joints())["bone_worst"] < 1e-9
        assert np.linalg.norm(moved.joints() - j, axis=-1).mean() < 0.01


def test_rigid_motion_basics(wave):
    m = fit_rigid(wave[:5])
    assert len(m) == 5 and isinstance(m, RigidMotion)
    shifted = m.translated(np.array([1.0, 0.0, 0.0]))
    assert np.allclose(shifted.joints() - m.joints(), [1.0, 0.0, 0.0])
    dev = bone_length_deviation(stretch(wave, 0.1, slice(3, 4)))
    assert abs(dev["bone_worst"] - 0.1) < 1e-6 and 0 < dev["bone_std"] < 0.01


def test_first_frame_conventions(wave):
    """'consistent' puts frame 0 in the same kind of body frame as the others: no yaw jump in the first yaw
    velocity; the motion is the same up to its heading."""
    from stablemofusion.footskate.cleanup import align_yaw_xz

    turned = wave.copy()
    turned[:, :, [0, 2]] = wave[:, :, [2, 0]] * [1.0, -1.0]  # start facing sideways
    official = features_from_joints(turned)
    consistent = features_from_joints(turned, first_frame="consistent")
    assert abs(consistent[0, 0]) < 0.1 * abs(official[0, 0]) + 1e-6
    a, b = joints_from_features(official), joints_from_features(consistent)
    assert np.abs(align_yaw_xz(b, a) - a).max() < 1e-6
    with pytest.raises(MotionFormatError, match="first_frame must be one of"):
        features_from_joints(wave, first_frame="first")
