"""Checkpoint folders: a student's teacher (`teacher_folder`) and the files that go with a model
(`companion_file`: a teacher shipped inside its student's folder uses the student's text side)."""

import shutil

import numpy as np
import pytest

from stablemofusion.diffusion.checkpoint import TEACHER_DIR, companion_file, teacher_folder
from stablemofusion.core.errors import SMFError
from stablemofusion.text import ACTIONS_FILE, LENGTH_WEIGHTS

MEAN, STD = np.zeros(263), np.full(263, 0.1)


@pytest.fixture(scope="module")
def teacher(tmp_path_factory, save_tiny_checkpoint):
    return save_tiny_checkpoint(tmp_path_factory.mktemp("teacher") / "teacher", MEAN, STD)


def test_teacher_folder_resolves_absolute_and_relative_names(tmp_path, teacher, save_tiny_student):
    absolute = save_tiny_student(tmp_path / "a", teacher)
    assert teacher_folder(absolute) == teacher
    shipped = save_tiny_student(tmp_path / "b", teacher, name=TEACHER_DIR)  # relative: to the student's folder
    shutil.copytree(teacher, shipped / TEACHER_DIR)
    assert teacher_folder(shipped) == shipped / TEACHER_DIR
    run = tmp_path / "run"  # a run folder: its checkpoint/ is the student
    shutil.copytree(shipped, run / "checkpoint")
    assert teacher_folder(run) == run / "checkpoint" / TEACHER_DIR


def test_teacher_folder_errors_name_the_problem(tmp_path, teacher, save_tiny_student):
    with pytest.raises(SMFError, match="not a distilled student: it has no teacher"):
        teacher_folder(teacher)
    lost = save_tiny_student(tmp_path / "lost", teacher, name=TEACHER_DIR)  # names teacher/, which is absent
    with pytest.raises(SMFError, match="is not there"):
        teacher_folder(lost)
    with pytest.raises(SMFError, match="not a checkpoint folder"):
        teacher_folder(tmp_path / "nothing")


def test_a_teacher_inside_its_students_folder_uses_the_students_text_side(tmp_path, teacher, save_tiny_student):
    student = save_tiny_student(tmp_path / "student", teacher, name=TEACHER_DIR)
    inside = shutil.copytree(teacher, student / TEACHER_DIR)
    (student / ACTIONS_FILE).write_text("{}")
    assert companion_file(student, ACTIONS_FILE) == student / ACTIONS_FILE
    assert companion_file(inside, ACTIONS_FILE) == student / ACTIONS_FILE  # the parent student's
    assert companion_file(inside, LENGTH_WEIGHTS) is None  # neither has it
    (inside / ACTIONS_FILE).write_text("{}")
    assert companion_file(inside, ACTIONS_FILE) == inside / ACTIONS_FILE  # its own comes first


def test_only_the_teacher_its_parent_names_uses_the_parents_files(tmp_path, teacher, save_tiny_student):
    other = save_tiny_student(tmp_path / "other", teacher)  # a student naming a teacher elsewhere
    stranger = shutil.copytree(teacher, other / TEACHER_DIR)
    (other / ACTIONS_FILE).write_text("{}")
    assert companion_file(stranger, ACTIONS_FILE) is None
    plain = shutil.copytree(teacher, tmp_path / "plain")  # an ordinary model's subfolder is no teacher of it
    inside = shutil.copytree(teacher, plain / TEACHER_DIR)
    (plain / ACTIONS_FILE).write_text("{}")
    assert companion_file(inside, ACTIONS_FILE) is None
