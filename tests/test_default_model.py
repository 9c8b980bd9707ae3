"""The default model shipped inside the package: small, documented, loads offline, generates the main job."""

import json

import numpy as np
import pytest
import torch

from stablemofusion.cli.main import main
from stablemofusion.motion.skeleton import HUMANML3D
from stablemofusion.motion.features import joints_from_features
from stablemofusion.motion.files import load_motion
from stablemofusion.pipeline import MotionPipeline, default_model_path


@pytest.fixture(scope="module")
def pipe():
    torch.set_num_threads(1)
    return MotionPipeline.from_pretrained(None, device="cpu")


def test_shipped_files_size_licence_and_config():
    path = default_model_path()
    assert path is not None, "the default model must ship inside the package"
    size = sum(f.stat().st_size for f in path.iterdir())
    assert size <= 25e6
    assert not (path / "training_state.pt").exists() and not (path / "ema.safetensors").exists()
    card = (path / "MODEL_CARD.md").read_text()
    for words in ("CC BY-NC 4.0", "non-commercial", "smf train", "Bandai-Namco"):
        assert words in card
    config = json.loads((path / "config.json").read_text())
    assert config["text_encoder"] == "minilm" and config["export"]["dtype"] == "float16"
    assert np.load(path / "Mean.npy").shape == (263,) and np.load(path / "Std.npy").shape == (263,)


def test_default_model_generates_plausible_motion(pipe):
    out = pipe(["a person walks forward normally"], seconds=4, seed=0)[0]
    assert out.features.shape == (80, 263) and np.isfinite(out.features).all()
    j = out.joints
    height = j[:, 15, 1] - np.minimum(j[:, 10, 1], j[:, 11, 1])  # head above the lower foot
    assert 1.2 < np.median(height) < 2.1  # a standing adult, not noise
    assert np.linalg.norm(j[-1, 0, [0, 2]] - j[0, 0, [0, 2]]) > 0.5  # a walk travels (4 s at >= 0.125 m/s)


def test_main_command_writes_video_joints_and_bvh(tmp_path, capsys):
    assert main(["generate", "a person waves both hands happily", "--out", str(tmp_path), "--seconds", "3",
                 "--footskate", "post"]) == 0
    stem = "000_a_person_waves_both_hands_happily"
    joints = np.load(tmp_path / f"{stem}_joints.npy")
    assert joints.shape == (60, 22, 3)
    assert (tmp_path / f"{stem}.mp4").stat().st_size > 10_000
    back = load_motion(tmp_path / f"{stem}.bvh")
    assert np.linalg.norm(back.joints - joints, axis=-1).max() < 1e-3  # the BVH is the same rigid motion
    lengths = np.linalg.norm(joints[:, 1:] - joints[:, list(HUMANML3D.parents[1:])], axis=-1)
    assert np.abs(lengths - np.asarray(HUMANML3D.bone_lengths[1:])).max() < 1e-4  # the dataset skeleton, every frame
    np.testing.assert_allclose(joints_from_features(np.load(tmp_path / f"{stem}_features.npy")), joints, atol=1e-5)
