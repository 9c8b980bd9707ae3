"""footskate='off'|'post'|'loop' in the pipeline and `smf generate`; the `smf footskate` commands."""

import json

import numpy as np
import pytest
import torch

from stablemofusion.cli.main import main
from stablemofusion.core.errors import SMFError
from stablemofusion.footskate import FootskateOptions
from stablemofusion.pipelines.motion_pipeline import MotionPipeline


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory, save_tiny_checkpoint):
    mean, std = np.zeros(263), np.full(263, 0.1)
    mean[3] = 0.9  # root height: stand above the floor
    return save_tiny_checkpoint(tmp_path_factory.mktemp("fs-ckpt") / "checkpoint", mean, std)


@pytest.fixture(scope="module")
def pipe(checkpoint):
    torch.set_num_threads(1)
    return MotionPipeline.from_pretrained(checkpoint, device="cpu")


def test_post_is_the_default_and_off_without_the_rigid_stage(pipe, checkpoint):
    from stablemofusion.core.limits import FOOTSKATE

    assert FOOTSKATE == "post" and pipe.settings().footskate == "post"
    a = pipe(["a person walks"], frames=40, steps=3, seed=1)[0]
    b = pipe(["a person walks"], frames=40, steps=3, seed=1, footskate="post")[0]
    assert np.array_equal(a.features, b.features)
    raw = MotionPipeline.from_pretrained(checkpoint, device="cpu", rigid=None)
    assert raw.settings().footskate == "off"  # the cleanup works on the rigid body


@pytest.mark.parametrize("mode", ["post", "loop"])
def test_post_and_loop_run(pipe, mode):
    off = pipe(["a person walks", "a man jumps"], frames=[40, 48], steps=4, seed=1, footskate="off")
    res = pipe(["a person walks", "a man jumps"], frames=[40, 48], steps=4, seed=1, footskate=mode)
    for r, o in zip(res, off):
        assert r.features.shape == o.features.shape and np.isfinite(r.features).all()
        assert not np.array_equal(r.features, o.features)


def test_loop_steps():
    opt = FootskateOptions(loop_steps=3, loop_skip_last=1)
    assert [k for k in range(10) if opt.in_loop(k, 10)] == [6, 7, 8]
    assert [k for k in range(2) if opt.in_loop(k, 2)] == [0]
    assert [k for k in range(10) if FootskateOptions().in_loop(k, 10)] == [8, 9]


def test_bad_mode(pipe):
    with pytest.raises(SMFError, match="footskate must be one of"):
        pipe("x", frames=40, steps=2, footskate="on")


def test_generate_cli_footskate(checkpoint, tmp_path, capsys):
    argv = ["generate", "a person walks", "--seconds", "2", "--out", str(tmp_path), "--checkpoint", str(checkpoint),
            "--format", "npy", "--steps", "3", "--footskate", "post"]
    assert main(argv) == 0
    assert np.load(tmp_path / "000_a_person_walks_features.npy").shape == (40, 263)
    with pytest.raises(SystemExit) as e:  # argparse rejects it
        main(argv[:-1] + ["sideways"])
    assert e.value.code == 2
    assert main(argv + ["--contacts", "vgrf", "--vgrf-model", str(tmp_path / "none.safetensors")]) == 2
    assert "vGRF model not found" in capsys.readouterr().err


def test_footskate_clean_and_contacts_cli(tmp_path, capsys):
    assert main(["footskate", "contacts", "example:wave-both-hands"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 118 and out["skate_ratio"] == 0.0
    assert main(["footskate", "clean", "example:wave-both-hands", "--out", str(tmp_path / "w")]) == 0
    assert np.load(tmp_path / "w_features.npy").shape == (118, 263)
    assert main(["footskate", "contacts", "example:nope"]) == 2


def test_footskate_clean_cli_keeps_a_features_file_untouched_dims(tmp_path, wave):
    """A features input keeps the dimensions the cleanup does not change (here: noisy head rotations that
    inverse kinematics of the positions would replace)."""
    from stablemofusion.motion.features import features_from_joints

    feats = features_from_joints(np.concatenate([wave, wave[-1:]])).astype(np.float32)
    head = slice(67 + 14 * 6, 67 + 15 * 6)  # rotation of joint 15 (head)
    feats[:, head] += np.random.default_rng(0).normal(0, 0.1, feats[:, head].shape).astype(np.float32)
    np.save(tmp_path / "in.npy", feats)
    assert main(["footskate", "clean", str(tmp_path / "in.npy"), "--out", str(tmp_path / "w")]) == 0
    out = np.load(tmp_path / "w_features.npy")
    assert out.shape == feats.shape
    assert np.abs(out[:, head] - feats[:, head]).max() < 1e-3  # recomputing them would differ by ~0.1
