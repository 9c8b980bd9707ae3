"""Release export: EMA weights only, float16, model card inside, loads back as a pipeline; a student with its
teacher inside (the shipped layout)."""

import re

import numpy as np
import torch
from safetensors.torch import load_file

from stablemofusion.cli.main import main
from stablemofusion.diffusion.checkpoint import EMA, MODEL, STATE, load_checkpoint, save_checkpoint
from stablemofusion.diffusion.config import CheckpointConfig
from stablemofusion.models.registry import build_denoiser
from stablemofusion.models.presets import get_preset


def test_export_keeps_ema_weights_in_fp16(tmp_path, capsys):
    torch.manual_seed(0)
    cfg = get_preset("tiny")
    model = build_denoiser(cfg)
    ema = {k: v + 0.5 if v.is_floating_point() else v for k, v in model.state_dict().items()}
    src = tmp_path / "run" / "checkpoint"
    save_checkpoint(src, model=model, mean=np.zeros(263), std=np.ones(263), ema_state=ema, training_state={"step": 3},
                    config=CheckpointConfig.for_skeleton(cfg, step=3))
    card = tmp_path / "card.md"
    card.write_text("# card\nnon-commercial\n")
    out = tmp_path / "release"
    assert main(["export", "--checkpoint", str(tmp_path / "run"), "--out", str(out), "--card", str(card)]) == 0
    assert "MB" in capsys.readouterr().out
    assert (out / "MODEL_CARD.md").read_text() == card.read_text()
    assert not (out / EMA).exists() and not (out / STATE).exists()
    weights = load_file(out / MODEL)
    key = next(k for k, v in weights.items() if v.is_floating_point())
    assert weights[key].dtype == torch.float16
    torch.testing.assert_close(weights[key].float(), ema[key].half().float())
    ck = load_checkpoint(out)
    assert ck.config.export.from_step == 3
    assert main(["export", "--checkpoint", str(tmp_path / "nope"), "--out", str(out)]) == 2


def test_export_ships_a_student_with_its_teacher_inside(tmp_path, capsys, save_tiny_checkpoint, save_tiny_student):
    """The shipped layout: the student at the top with the text side, its teacher in teacher/ (named relative,
    so the folder can move), both fp16 EMA weights; the pipeline loads either, the teacher with the student's
    text side."""
    import json
    import shutil

    from stablemofusion.diffusion.checkpoint import CONFIG, TEACHER_DIR, teacher_folder
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline, default_model_path
    from stablemofusion.text import TEXT_SIDE_FILES

    teacher = save_tiny_checkpoint(tmp_path / "teacher", np.zeros(263), np.full(263, 0.1))
    student = save_tiny_student(tmp_path / "student", teacher)
    text_side = tmp_path / "text-side"
    text_side.mkdir()
    present = [n for n in TEXT_SIDE_FILES if (default_model_path() / n).is_file()]  # its embeddings are in its graphs
    for name in present:
        shutil.copy(default_model_path() / name, text_side / name)
    card = tmp_path / "card.md"
    card.write_text("# the pair\n")
    out = tmp_path / "release"
    assert main(["export", "--checkpoint", str(student), "--teacher-folder", str(teacher), "--text-side",
                 str(text_side), "--card", str(card), "--out", str(out)]) == 0
    own = {CONFIG, MODEL, "Mean.npy", "Std.npy"}
    assert {f.name for f in out.iterdir()} == own | set(present) | {"MODEL_CARD.md", TEACHER_DIR}
    assert {f.name for f in (out / TEACHER_DIR).iterdir()} == own  # the text side once, in the student's folder
    config = json.loads((out / CONFIG).read_text())
    assert config["distil"]["teacher"] == TEACHER_DIR and config["export"]["dtype"] == "float16"
    inner = load_checkpoint(out / TEACHER_DIR)
    assert not inner.config.student and inner.config.export.dtype == "float16"
    assert all(v.dtype == torch.float16 for v in load_file(out / TEACHER_DIR / MODEL).values() if v.is_floating_point())
    moved = shutil.move(out, tmp_path / "moved")  # a relative name: the pair still finds each other
    student_pipe = MotionPipeline.from_pretrained(moved, device="cpu")
    teacher_pipe = MotionPipeline.from_pretrained(moved, teacher=True, device="cpu")
    assert student_pipe.student and not teacher_pipe.student
    for pipe in (student_pipe, teacher_pipe):
        assert pipe.known_actions is not None and pipe.length_estimator is not None
    assert main(["export", "--checkpoint", str(moved), "--out", str(tmp_path / "alone")]) == 0  # no teacher inside
    assert teacher_folder(tmp_path / "alone") == (tmp_path / "moved" / TEACHER_DIR).resolve()  # still names it


def test_export_carries_the_checkpoints_own_text_side(tmp_path, save_tiny_checkpoint):
    import shutil

    from stablemofusion.pipelines.motion_pipeline import default_model_path
    from stablemofusion.text import LENGTH_CONFIG, LENGTH_WEIGHTS

    src = save_tiny_checkpoint(tmp_path / "ck", np.zeros(263), np.full(263, 0.1))
    for name in (LENGTH_CONFIG, LENGTH_WEIGHTS):
        shutil.copy(default_model_path() / name, src / name)
    assert main(["export", "--checkpoint", str(src), "--out", str(tmp_path / "out")]) == 0
    for name in (LENGTH_CONFIG, LENGTH_WEIGHTS):
        assert (tmp_path / "out" / name).read_bytes() == (src / name).read_bytes()


def test_export_of_a_pair_refuses_what_cannot_be_one(tmp_path, capsys, save_tiny_checkpoint, save_tiny_student):
    teacher = save_tiny_checkpoint(tmp_path / "teacher", np.zeros(263), np.full(263, 0.1))
    student = save_tiny_student(tmp_path / "student", teacher)
    other = save_tiny_checkpoint(tmp_path / "other", np.zeros(263), np.full(263, 0.2))  # another normalisation
    out = str(tmp_path / "out")
    cases = [(["--checkpoint", str(teacher), "--teacher-folder", str(teacher)], "only a student ships its teacher"),
             (["--checkpoint", str(student), "--teacher-folder", str(other)], "cannot be the teacher of .*Mean/Std"),
             (["--checkpoint", str(student), "--teacher-folder", str(student)], "itself a distilled student"),
             (["--checkpoint", str(student), "--text-side", str(teacher)], "has none of the text-side files")]
    for argv, message in cases:
        capsys.readouterr()
        assert main(["export", *argv, "--out", out]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("smf: error:"), err
        assert re.search(message, err), err
    assert not (tmp_path / "out").exists()


def test_export_records_the_models_default_guidance(tmp_path, capsys, save_tiny_checkpoint, save_tiny_student):
    """`smf export --guidance G`: the release samples with G where a call names no scale (at 1: the
    conditional pass alone), `smf generate` records it, `smf info` shows it; an explicit scale still wins; a
    student shipped with that teacher keeps its own default; a bad value is a one-line error."""
    import json

    from stablemofusion.diffusion.checkpoint import TEACHER_DIR
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.core.settings import GUIDANCE

    src = save_tiny_checkpoint(tmp_path / "ck", np.zeros(263), np.full(263, 0.1))
    out = tmp_path / "release"
    assert main(["export", "--checkpoint", str(src), "--out", str(out), "--guidance", "1", "--dtype", "float32"]) == 0
    assert load_checkpoint(out).config.guidance == 1.0
    pipe = MotionPipeline.from_pretrained(out, device="cpu")
    base = MotionPipeline.from_pretrained(src, device="cpu")
    assert pipe.settings().guidance_scale == 1.0 and base.settings().guidance_scale == GUIDANCE
    batches, denoise = [], pipe.model.denoise
    pipe.model.denoise = lambda x, *a, **kw: batches.append(int(x.shape[0])) or denoise(x, *a, **kw)
    default = pipe.denoise(["a person walks"], [40], steps=2, seed=0)
    assert batches == [1, 1]  # guidance 1: no unconditional pass
    batches.clear()
    strong = pipe.denoise(["a person walks"], [40], steps=2, seed=0, guidance_scale=GUIDANCE)
    assert batches == [2, 2] and not torch.allclose(default, strong)
    torch.testing.assert_close(default, pipe.denoise(["a person walks"], [40], steps=2, seed=0, guidance_scale=1.0))
    torch.testing.assert_close(strong, base.denoise(["a person walks"], [40], steps=2, seed=0))  # same weights
    assert pipe.stream("a person walks", seed=0).settings.guidance_scale == 1.0  # every task takes the default
    line = [("a person walks", 2.0), ("a person runs", 2.0)]
    np.testing.assert_allclose(pipe.timeline(line, seed=0, steps=2).joints,
                               pipe.timeline(line, seed=0, steps=2, guidance_scale=1.0).joints)
    gen = tmp_path / "gen"
    assert main(["generate", "a person walks", "--checkpoint", str(out), "--out", str(gen), "--format", "json",
                 "--seconds", "2", "--steps", "2", "--device", "cpu"]) == 0
    assert json.loads(next(gen.glob("*.json")).read_text())["guidance"] == 1.0
    capsys.readouterr()
    assert main(["info", "--checkpoint", str(out)]) == 0
    assert "default guidance scale 1 (its config)" in capsys.readouterr().out
    student = save_tiny_student(tmp_path / "student", src)
    pair = tmp_path / "pair"
    assert main(["export", "--checkpoint", str(student), "--teacher-folder", str(out), "--out", str(pair)]) == 0
    assert load_checkpoint(pair / TEACHER_DIR).config.guidance == 1.0 and load_checkpoint(pair).config.guidance is None
    capsys.readouterr()
    for bad in ("-1", "nan", "inf"):
        assert main(["export", "--checkpoint", str(src), "--out", str(tmp_path / "bad"), "--guidance", bad]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "guidance" in err, err
    assert not (tmp_path / "bad").exists()
