"""The UnderPressure port: loading, FK, the S1_Hopping figures, retargeting and resampling."""

import numpy as np
import pytest
import torch

from stablemofusion.core.errors import SMFError
from stablemofusion.footskate.contacts import contact_f1, contacts_from_underpressure_labels, contacts_from_vgrf
from stablemofusion.footskate.underpressure import (UP_PARENTS, UP_REST, TeacherOn22, UnderPressureNet,
                                                    forward_kinematics_23, load_underpressure, resample_time,
                                                    retarget_22_to_23, vgrf_from_joints22, vgrf_from_joints23)


@pytest.fixture(scope="module")
def net(up_weights):
    torch.set_num_threads(1)
    return load_underpressure(up_weights)


def test_port_matches_measured_forces_on_s1(net, s1):
    pred = vgrf_from_joints23(net, s1["joints"]).sum(-1)  # (F, 2) per-foot totals
    true = s1["forces"].sum(-1)
    rmse = np.sqrt(((pred - true) ** 2).mean())
    corr = np.corrcoef(pred.ravel(), true.ravel())[0, 1]
    assert rmse < 0.08 and corr > 0.99, (rmse, corr)  # published port: ~0.07 and ~0.996
    # foot 0 is the left foot: the left prediction follows the left measurement better than the right one
    assert np.corrcoef(pred[:, 0], true[:, 0])[0, 1] > np.corrcoef(pred[:, 0], true[:, 1])[0, 1]
    f1 = contact_f1(contacts_from_vgrf(vgrf_from_joints23(net, s1["joints"]), 100.0),
                    contacts_from_underpressure_labels(s1["contacts"]))
    assert f1 > 0.93


def test_fk_rest_pose_is_the_skeleton():
    F = 3
    q = np.zeros((F, 23, 4))
    q[..., 0] = 1.0
    traj = np.arange(F * 3, dtype=float).reshape(F, 1, 3)
    pos = forward_kinematics_23(q, UP_REST[None], traj)
    assert np.allclose(pos, UP_REST[None] + traj)
    t = forward_kinematics_23(torch.tensor(q), torch.tensor(UP_REST[None]), torch.tensor(traj))
    assert np.allclose(t.numpy(), pos)


@pytest.mark.parametrize("content", [b"not a torch file", None])
def test_load_errors(tmp_path, content):
    path = tmp_path / "pretrained.tar"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(SMFError, match="UnderPressure|not a readable"):
        load_underpressure(path)


def test_load_wrong_state_dict(tmp_path):
    path = tmp_path / "other.tar"
    torch.save({"model": {"0.weight": torch.zeros(3)}}, path)
    with pytest.raises(SMFError, match="not an UnderPressure state dict"):
        load_underpressure(path)


def test_retarget_shapes_bones_and_floor(wave):
    j23 = retarget_22_to_23(wave)
    assert j23.shape == (len(wave), 23, 3)
    rest = np.linalg.norm(UP_REST[1:] - UP_REST[list(UP_PARENTS[1:])], axis=-1)
    got = np.linalg.norm(j23[:, 1:] - j23[:, list(UP_PARENTS[1:])], axis=-1)
    assert np.allclose(got, rest[None], atol=1e-6)  # UnderPressure's bone lengths
    assert abs(j23[:, [18, 22], 2].min() - wave[:, [10, 11], 1].min()) < 1e-6  # same floor, Z up
    assert (j23[:, 6, 2] > j23[:, 0, 2]).all()  # head above pelvis: Z is up
    x = torch.tensor(wave, requires_grad=True)
    y = retarget_22_to_23(x)
    assert np.allclose(y.detach().numpy(), j23, atol=1e-6)
    y.sum().backward()
    assert torch.isfinite(x.grad).all()


def test_resample_time_roundtrip():
    x = torch.linspace(0, 1, 21).reshape(21, 1, 1).expand(21, 2, 3)
    up = resample_time(x, 20.0, 100.0)
    assert up.shape == (101, 2, 3)
    assert torch.allclose(resample_time(up, 100.0, 20.0), x, atol=1e-6)


def test_vgrf_of_a_standing_motion_is_about_body_weight(net, wave):
    f = vgrf_from_joints22(net, wave)
    assert f.shape == (len(wave), 2, 16)
    assert 0.7 < f.sum((1, 2)).mean() < 1.3
    t = TeacherOn22(net)(torch.tensor(wave[None], dtype=torch.float32))
    assert t.shape == (1, len(wave), 2, 16)
    assert np.allclose(t[0].detach().numpy(), f, atol=0.02)


def test_network_shapes_without_weights():
    out = UnderPressureNet().eval()(torch.zeros(2, 30, 23, 3))
    assert out.shape == (2, 30, 2, 16) and (out >= 0).all()


def test_retarget_23_to_22_and_back_keeps_the_port_close(net, s1):
    from stablemofusion.footskate.underpressure import retarget_23_to_22
    from stablemofusion.motion.resample import resample

    j22 = retarget_23_to_22(s1["joints"][:1000])  # 100 -> 20 fps
    assert j22.shape == (200, 22, 3)
    assert (j22[:, 15, 1] > j22[:, 0, 1]).all()  # Y up
    pred = vgrf_from_joints22(net, j22).sum(-1)
    true = resample(s1["forces"][:1000].astype(float), 100.0, 20.0).sum(-1)
    assert np.sqrt(((pred - true) ** 2).mean()) < 0.12
