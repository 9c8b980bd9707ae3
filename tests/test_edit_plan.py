"""Editing with known answers: kept frames and the kept half of the body are the source's, a trajectory is
followed, seams have no jump; root math; bad input is one line."""

import numpy as np
import pytest
import torch

from stablemofusion.cli.main import main
from stablemofusion.core.edit_plan import blend_seams, body_mask, plan_edit, source_features
from stablemofusion.core.errors import SMFError
from stablemofusion.motion.features import features_from_joints, joints_from_features
from stablemofusion.motion.files import load_motion
from stablemofusion.motion.root import follow_path, headings, land_at, place_like, root_xz
from stablemofusion.motion.skeleton import HUMANML3D
from stablemofusion.pipelines.motion_pipeline import MotionPipeline


@pytest.fixture(scope="module")
def pipe():
    return MotionPipeline.from_pretrained(device="cpu")  # the shipped model


@pytest.fixture(scope="module")
def source():
    """A real captured motion (Bandai-Namco, shipped as an example): 117 feature frames."""
    return features_from_joints(load_motion("example:wave-both-hands").joints)


def accel(joints: np.ndarray, fps: float = 20.0) -> np.ndarray:
    """(T, J, 3) -> (T-2,) largest joint acceleration per frame (m/s^2)."""
    return np.linalg.norm((joints[2:] - 2 * joints[1:-1] + joints[:-2]) * fps ** 2, axis=-1).max(-1)


def test_root_math_lands_and_follows_exactly(source):
    f = torch.from_numpy(source)
    other = torch.flip(f, [0])
    path = root_xz(other)
    assert torch.allclose(root_xz(follow_path(f, path)), path, atol=1e-9)
    landed = land_at(f, 10, 90, headings(other)[90], root_xz(other)[90])
    assert torch.allclose(headings(landed)[90], headings(other)[90]) and torch.allclose(root_xz(landed)[90],
                                                                                       root_xz(other)[90])
    assert torch.equal(landed[:10], f[:10]) and torch.equal(landed[90:, 3:], f[90:, 3:])
    whole, tail = joints_from_features(f), joints_from_features(f[40:])
    ft = f[40:]
    placed = place_like(tail.numpy(), 0, float(headings(ft)[0]), root_xz(ft)[0].numpy(), float(headings(f)[40]),
                        root_xz(f)[40].numpy())  # numpy: placing the output is post-processing
    assert np.allclose(placed, whole[40:].numpy(), atol=1e-9)
    # the root math is written once for numpy and torch
    n = source
    assert np.allclose(root_xz(follow_path(n, path.numpy())), path.numpy(), atol=1e-9)
    assert np.allclose(land_at(n, 10, 90, float(headings(other)[90]), root_xz(other)[90].numpy()), landed.numpy())


def test_blend_seams_removes_the_jump_and_keeps_kept_frames():
    T, D = 60, 263
    f = torch.zeros(T, D, dtype=torch.float64)
    f[:, 4] = torch.arange(T, dtype=torch.float64) * 0.01  # a joint moving at a steady pace
    f[30:, 4] += 0.5  # the generated part starts 0.5 away: a jump
    kept = torch.zeros(T, dtype=torch.bool)
    kept[:30] = True
    out = blend_seams(f, kept)
    assert torch.equal(out[:30], f[:30]) and torch.equal(out[40:], f[40:])
    assert float(out[:, 4].diff().diff().abs().max()) < 0.1 * 0.5  # was 0.5: at most a tenth of it
    # and backwards, before a kept block
    g, kept2 = torch.flip(f, [0]), torch.flip(kept, [0])
    back = blend_seams(g, kept2)
    assert torch.equal(back[30:], g[30:]) and float(back[:, 4].diff().diff().abs().max()) < 0.1 * 0.5
    assert torch.allclose(back[29, 4], 2 * g[30, 4] - g[31, 4])  # where the block's first step leads back to


def test_body_mask_covers_the_lower_body():
    m = body_mask(HUMANML3D, HUMANML3D.lower_body, root=True)
    assert m[:4].all() and m[-4:].all() and m.sum() == 4 + 8 * 3 + 8 * 6 + 9 * 3 + 4


@pytest.mark.parametrize("mode, kw", [("prefix", dict(keep_start=1.5)), ("suffix", dict(keep_end=1.5)),
                                      ("inbetween", dict(keep_start=1.0, keep_end=1.0))])
@pytest.mark.parametrize("impose", ["x0", "xt"])
def test_kept_frames_are_the_source(pipe, source, mode, kw, impose):
    ref = joints_from_features(source)
    r = pipe.edit("a person jumps up and down", source, mode, seed=0, impose=impose, **kw)
    T, n_s, n_e = len(r.joints), int(kw.get("keep_start", 0) * 20), int(kw.get("keep_end", 0) * 20)
    out = list(range(n_s)) + list(range(T - n_e, T))
    src = list(range(n_s)) + list(range(len(source) - n_e, len(source)))
    assert T == len(source) and np.abs(r.joints[out] - ref[src]).max() < 0.01  # the bar: 1 cm
    # the features decode to the same joints, and the edit changed the generated part
    assert np.abs(joints_from_features(r.features) - r.joints).max() < 0.01 or mode == "suffix"
    gen = [i for i in range(T) if i not in out]
    assert np.abs(r.joints[gen] - ref[gen]).max() > 0.05
    real = accel(ref).max()
    for b in ([n_s] if n_s else []) + ([T - n_e] if n_e else []):
        assert accel(r.joints)[b - 2:b].max() <= real  # no pop: within the source's own range


def test_upper_body_keeps_the_lower_body(pipe, source):
    ref = joints_from_features(source)
    r = pipe.edit("a person punches forward", source, "upper-body", seed=1)
    lower, upper = list(HUMANML3D.lower_body), [j for j in range(22) if j not in HUMANML3D.lower_body]
    assert np.abs(r.joints[:, lower] - ref[:, lower]).max() < 0.01
    assert np.abs(r.joints[:, upper] - ref[:, upper]).max() > 0.05


def test_lower_body_keeps_the_upper_body_pose(pipe, source):
    """The upper body's local joint rotations are the source's (its rigid fit's); the root and legs move anew."""
    src_motion = pipe.finish(source)[1]
    r = pipe.edit("a person walks forward", source, "lower-body", seed=0)
    upper = [j for j in range(1, 22) if j not in HUMANML3D.lower_body]
    assert np.abs(r.motion.rotations[:, upper] - src_motion.rotations[:, upper]).max() < 1e-9
    moved = np.linalg.norm(r.joints[-1, 0, [0, 2]] - r.joints[0, 0, [0, 2]])
    assert moved > 0.5  # the source waves in place; the edit walks (0.8 m when written)


def test_trajectory_is_followed(pipe, source, tmp_path):
    t = np.linspace(0, 1, 80)
    path = np.stack([np.sin(t * np.pi) * 1.5, t * 2.0], -1)  # an arc: 2 m forward, 1.5 m to the side
    r = pipe.edit("a person walks", source, "trajectory", path=path, seed=0)
    assert len(r.joints) == 80
    assert np.linalg.norm(r.joints[:, 0, [0, 2]] - (path - path[0]), axis=-1).mean() < 0.10


def test_source_features_converts_joints_at_another_frame_rate(source):
    m = load_motion("example:wave-both-hands")
    m30 = type(m)(np.repeat(m.joints, 3, axis=0)[::2], m.skeleton, 30.0)  # the same motion at 30 fps
    f = source_features(m30, HUMANML3D, 20.0, given_fps=30.0)
    assert abs(len(f) - len(source)) <= 1


@pytest.mark.parametrize("mode, kw, msg", [
    ("sideways", {}, "edit mode must be one of"),
    ("prefix", {}, "keep-start must keep"),
    ("inbetween", dict(keep_start=50, keep_end=80), "keep-end must keep"),
    ("upper-body", dict(frames=40), "keep the source's length"),
    ("trajectory", dict(path=np.zeros((10, 3))), "a path is a finite"),
    ("trajectory", dict(path=np.zeros(())), "a path is a finite"),
    ("trajectory", dict(path=np.zeros((50, 2)), frames=60), "as long as its path"),
])
def test_bad_plans_are_one_line_errors(source, mode, kw, msg):
    with pytest.raises(SMFError, match=msg):
        plan_edit(mode, source, HUMANML3D, **kw)


def test_smf_edit_writes_files_and_rejects_bad_input(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["edit", "a person bows", "--motion", "example:wave-both-hands", "--mode", "suffix", "--keep-end",
                 "1", "--format", "npy,bvh,json", "--out", str(out), "--steps", "4"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert any(n.endswith("_joints.npy") for n in names) and any(n.endswith(".bvh") for n in names)
    assert main(["edit", "a person bows", "--motion", "nope.npy", "--mode", "prefix", "--out", str(out)]) == 2
    assert main(["edit", "x", "--motion", "example:wave-both-hands", "--mode", "prefix", "--keep-start", "-1",
                 "--out", str(out)]) == 2
    assert main(["edit", "x", "--motion", "example:wave-both-hands", "--mode", "prefix", "--path", "p.npy",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "no such file" in err and "must be a finite number" in err and "--path is for --mode trajectory" in err
