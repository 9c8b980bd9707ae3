"""Shared command-line flags: `--teacher` on every command that takes `--checkpoint` (sample with the model's
teacher instead of its distilled student), and its one-line error for a model without a teacher."""

import json

import numpy as np
import pytest

from stablemofusion.cli.main import main
from stablemofusion.core.errors import SMFError
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.core.limits import SAMPLER, STEPS, STUDENT_SAMPLER


@pytest.fixture(scope="module")
def ordinary(tmp_path_factory, save_tiny_checkpoint):
    """A model that is no student: it has no teacher."""
    return save_tiny_checkpoint(tmp_path_factory.mktemp("plain") / "model", np.zeros(263), np.full(263, 0.1))


@pytest.fixture(scope="module")
def student(tmp_path_factory, ordinary, save_tiny_student):
    return save_tiny_student(tmp_path_factory.mktemp("student") / "student", ordinary)


def _commands(checkpoint, d):
    return [["generate", "a person walks", "--seconds", "2", "--out", f"{d}/o"],
            ["edit", "a person waves", "--motion", "example:wave-both-hands", "--mode", "upper-body", "--out",
             f"{d}/o"],
            ["serve", "--port", "8765"],
            ["bench", "--batch-sizes", "1", "--repeats", "1"],
            ["evaluate", "--data", str(d), "--evaluator", str(d)],
            ["ablate", "samplers", "--data", str(d), "--evaluator", str(d), "--out", f"{d}/a.json"]]


@pytest.mark.parametrize("command", range(6), ids=["generate", "edit", "serve", "bench", "evaluate", "ablate"])
def test_teacher_of_a_model_without_one_is_a_one_line_error(ordinary, tmp_path, capsys, command):
    argv = _commands(ordinary, tmp_path)[command] + ["--checkpoint", str(ordinary), "--teacher"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("smf: error:") and err.count("\n") == 1 and "Traceback" not in err
    assert "is not a distilled student: it has no teacher" in err
    assert not (tmp_path / "o").exists()


def test_teacher_flag_errors_that_need_no_model(tmp_path, capsys):
    assert main(["evaluate", "--data", str(tmp_path), "--checkpoint", "none", "--teacher"]) == 2
    assert "--teacher needs a model" in capsys.readouterr().err
    assert main(["bench", "--preset", "tiny", "--teacher"]) == 2
    assert "not with --checkpoint, --teacher or --adapter" in capsys.readouterr().err


def test_teacher_flag_samples_with_the_students_teacher(student, tmp_path):
    for flags, expected in (([], (STUDENT_SAMPLER, 1, True)), (["--teacher"], (SAMPLER, STEPS, False))):
        out = tmp_path / ("teacher" if flags else "student")
        assert main(["generate", "a person walks", "--checkpoint", str(student), "--seconds", "2", "--format", "json",
                     "--out", str(out), "--device", "cpu", *flags]) == 0
        meta = json.loads(next(out.glob("*.json")).read_text())
        assert (meta["sampler"], meta["steps"], meta["student"]) == expected


def test_from_pretrained_teacher_true(student, ordinary):
    pipe = MotionPipeline.from_pretrained(student, teacher=True, device="cpu")
    assert not pipe.student and pipe.settings().steps == STEPS
    with pytest.raises(SMFError, match="no teacher"):
        MotionPipeline.from_pretrained(ordinary, teacher=True, device="cpu")
