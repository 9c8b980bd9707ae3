"""The default model shipped inside the package: small, documented, loads offline, generates the main job; a
1-step distilled student with its 10-step teacher in teacher/, one flag (--teacher, teacher=True) away."""

import json

import numpy as np
import pytest
import torch

from stablemofusion.adapters.file import weights_hash
from stablemofusion.cli.main import main
from stablemofusion.diffusion.checkpoint import (TEACHER_DIR, graphs_of, load_weights, read_config, teacher_folder,
                                                 weights_from_graphs)
from stablemofusion.core.errors import SMFError
from stablemofusion.models.registry import build_denoiser
from stablemofusion.motion.skeleton import HUMANML3D
from stablemofusion.motion.features import joints_from_features
from stablemofusion.motion.files import load_motion
from stablemofusion.pipelines.motion_pipeline import MotionPipeline, default_model_path
from stablemofusion.core.limits import SAMPLER, STEPS, STUDENT_SAMPLER
from stablemofusion.text import EMBEDDINGS_FILE, TEXT_SIDE_FILES


@pytest.fixture(scope="module")
def pipe():
    torch.set_num_threads(1)
    return MotionPipeline.from_pretrained(None, device="cpu")


@pytest.fixture(scope="module")
def teacher():
    torch.set_num_threads(1)
    return MotionPipeline.from_pretrained(None, teacher=True, device="cpu")


def test_shipped_files_size_licence_and_config():
    path = default_model_path()
    assert path is not None, "the default model must ship inside the package"
    files = [f for f in path.rglob("*") if f.is_file()]
    graphs = path / "onnx"  # the portable graphs: MiniLM (Apache-2.0) and the model's, for the torch-free runtime
    assert sum(f.stat().st_size for f in files if graphs not in f.parents) <= 3e6  # the text side; no weights twice
    assert sum(f.stat().st_size for f in files if graphs in f.parents) <= 80e6
    notes = (graphs / "README.md").read_text()
    assert "Apache-2.0" in notes and "CC BY-NC 4.0" in notes
    # each licence in a file beside what it covers: the weights' CC BY-NC 4.0, the text encoder's Apache-2.0
    assert (path / "LICENSE").read_text().startswith("Attribution-NonCommercial 4.0 International")
    assert "Apache License" in (graphs / "LICENSE-MiniLM").read_text() and "Version 2.0" in (graphs / "LICENSE-MiniLM").read_text()
    assert not list(path.rglob("training_state.pt")) and not list(path.rglob("ema.safetensors"))
    card = (path / "MODEL_CARD.md").read_text()
    for words in ("CC BY-NC 4.0", "non-commercial", "Bandai-Namco"):  # the licence of the weights is stated
        assert words in card
    for folder in (path, path / TEACHER_DIR):
        config = json.loads((folder / "config.json").read_text())
        assert config["text_encoder"] == "minilm" and config["export"]["dtype"] == "float16"
        assert np.load(folder / "Mean.npy").shape == (263,) and np.load(folder / "Std.npy").shape == (263,)


def test_the_default_model_is_a_one_step_student_with_its_teacher_inside():
    path = default_model_path()
    config = json.loads((path / "config.json").read_text())
    assert config["distil"]["teacher"] == TEACHER_DIR and config["distil"]["sample_steps"] == 1  # relative: movable
    assert teacher_folder(path) == path / TEACHER_DIR
    assert "distil" not in json.loads((path / TEACHER_DIR / "config.json").read_text())
    # the text side once, at the top; the teacher uses its parent's
    # (the known actions' embeddings once, in the graphs: text/known.py reads them there)
    assert all((path / name).is_file() and not (path / TEACHER_DIR / name).exists()
               for name in TEXT_SIDE_FILES if name != EMBEDDINGS_FILE)
    assert {f.name for f in (path / TEACHER_DIR).iterdir()} == {"config.json", "Mean.npy", "Std.npy"}


def test_the_default_model_holds_each_weight_once_in_its_graphs(tmp_path):
    """No weights file beside the graphs: the torch backend reads each weight from the graph that holds it, the
    same values (a weight the exporter transposed or reshaped is read back in the model's layout)."""
    path = default_model_path()
    assert not list(path.rglob("model.safetensors"))
    for folder, graphs in ((path, path / "onnx"), (path / TEACHER_DIR, path / "onnx" / TEACHER_DIR)):
        where, entry = graphs_of(folder)
        assert where == graphs
        weights = weights_from_graphs(where, entry)
        model = build_denoiser(read_config(folder).model)
        own = model.state_dict()
        assert set(weights) == set(own) and all(weights[k].shape == own[k].shape for k in own)
        assert {layout for _, _, layout, _ in entry["weights"].values()} == {"", "T"}  # both kinds are exercised
    # what an adapter records of its base: the sha256 of the weights files the folder had before (adapters still fit)
    assert weights_hash(path) == "d092fd58f8708e3fc066215c7e91519fbaeca3b396fac288499eb1254ab07f12"
    assert weights_hash(path / TEACHER_DIR) == "3d08bcb40bafcf890ff7e800f516ee0975811cb6163745df5583e45d0ed8c450"
    (tmp_path / "config.json").write_bytes((path / "config.json").read_bytes())  # a model without graphs
    with pytest.raises(SMFError, match="no weights file"):
        load_weights(tmp_path)


def test_teacher_true_selects_the_teacher_with_the_students_text_side(pipe, teacher):
    assert pipe.student and (pipe.settings().sampler, pipe.settings().steps) == (STUDENT_SAMPLER, 1)
    assert not teacher.student and (teacher.settings().sampler, teacher.settings().steps) == (SAMPLER, STEPS)
    # each model's own default guidance: the teacher's chosen on the validation split (docs/inference.md); the
    # student was regressed on the teacher's samples at that scale (smf distil --method regression), so it is its own
    assert teacher.config.guidance == 1.0 and pipe.config.guidance == 1.0 and pipe.settings().guidance_scale == 1.0
    assert pipe.config.distil.method == "regression" and pipe.config.distil.guidance_min == 1.0
    assert teacher.known_actions is not None and teacher.length_estimator is not None
    assert teacher.predict_seconds("a person walks forward") == pipe.predict_seconds("a person walks forward")


@pytest.mark.parametrize("which", ["student", "teacher"])
def test_default_model_generates_plausible_motion(pipe, teacher, which):
    out = (pipe if which == "student" else teacher)(["a person walks forward normally"], seconds=4, seed=0)[0]
    assert out.features.shape == (80, 263) and np.isfinite(out.features).all()
    j = out.joints
    height = j[:, 15, 1] - np.minimum(j[:, 10, 1], j[:, 11, 1])  # head above the lower foot
    assert 1.2 < np.median(height) < 2.1  # a standing adult, not noise
    assert np.linalg.norm(j[-1, 0, [0, 2]] - j[0, 0, [0, 2]]) > 0.5  # a walk travels (4 s at >= 0.125 m/s)


def test_generate_with_teacher_flag_samples_with_the_teacher(tmp_path):
    for flags, (sampler, steps, student, guidance) in (([], (STUDENT_SAMPLER, 1, True, 1.0)),
                                                       (["--teacher"], (SAMPLER, STEPS, False, 1.0))):
        out = tmp_path / ("t" if flags else "s")
        assert main(["generate", "a person walks forward", "--seconds", "2", "--format", "json", "--out", str(out),
                     *flags]) == 0
        meta = json.loads(next(out.glob("*.json")).read_text())
        assert (meta["sampler"], meta["steps"], meta["student"], meta["guidance"]) == (sampler, steps, student, guidance)


def test_main_command_writes_joints_bvh_and_glb(tmp_path, capsys):
    assert main(["generate", "a person waves both hands happily", "--out", str(tmp_path), "--seconds", "3",
                 "--footskate", "post"]) == 0
    stem = "000_a_person_waves_both_hands_happily"
    joints = np.load(tmp_path / f"{stem}_joints.npy")
    assert joints.shape == (60, 22, 3)
    assert (tmp_path / f"{stem}.glb").stat().st_size > 10_000 and not list(tmp_path.glob("*.mp4"))
    back = load_motion(tmp_path / f"{stem}.bvh")
    assert np.linalg.norm(back.joints - joints, axis=-1).max() < 1e-3  # the BVH is the same rigid motion
    lengths = np.linalg.norm(joints[:, 1:] - joints[:, list(HUMANML3D.parents[1:])], axis=-1)
    assert np.abs(lengths - np.asarray(HUMANML3D.bone_lengths[1:])).max() < 1e-4  # the dataset skeleton, every frame
    np.testing.assert_allclose(joints_from_features(np.load(tmp_path / f"{stem}_features.npy")), joints, atol=1e-5)
