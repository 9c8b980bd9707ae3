"""The holes a new user meets on the command line: each closed."""

import argparse

import numpy as np
import pytest

from stablemofusion.cli.main import main
from stablemofusion.core.edit_plan import source_features
from stablemofusion.core.errors import SMFError
from stablemofusion.motion.files import load_motion, save_bvh
from stablemofusion.motion.skeleton import HUMANML3D
from stablemofusion.pipelines.motion_pipeline import MotionPipeline




@pytest.fixture(scope="module")
def pipe():
    return MotionPipeline.from_pretrained(device="cpu")


def _option_names(command: str) -> set[str]:
    from stablemofusion.cli.main import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return {o for a in sub.choices[command]._actions for o in a.option_strings}


def test_edit_has_every_generate_option_that_applies():
    only_generate = {"--prompts", "--timeline", "--batch-size"}
    assert _option_names("generate") - only_generate <= _option_names("edit")


def test_edit_of_a_bvh_keeps_the_source_frame_count(tmp_path, capsys):
    joints = load_motion("example:wave-both-hands").joints  # 118 frames
    save_bvh(joints, tmp_path / "src.bvh", HUMANML3D, 20.0)
    n = len(load_motion(tmp_path / "src.bvh").joints)
    assert main(["edit", "a person waves", "--motion", str(tmp_path / "src.bvh"), "--mode", "prefix",
                 "--keep-start", "1", "--steps", "2", "--format", "npy", "--out", str(tmp_path / "o")]) == 0
    out = np.load(next((tmp_path / "o").glob("*_joints.npy")))
    assert len(out) == n


def test_edit_with_the_student_takes_its_edit_steps_and_teacher_its_own(tmp_path):
    """The shipped student edits at STUDENT_EDIT_STEPS (at 1 step its only prediction never sees the kept part);
    --teacher edits with the teacher's defaults. The JSON records what was used."""
    import json

    from stablemofusion.core.limits import SAMPLER, STEPS, STUDENT_SAMPLER, STUDENT_EDIT_STEPS

    for flags, expected in (([], (STUDENT_SAMPLER, STUDENT_EDIT_STEPS)), (["--teacher"], (SAMPLER, STEPS))):
        out = tmp_path / ("t" if flags else "s")
        assert main(["edit", "a person waves", "--motion", "example:wave-both-hands", "--mode", "prefix",
                     "--keep-start", "1", "--format", "json", "--out", str(out), *flags]) == 0
        meta = json.loads(next(out.glob("*.json")).read_text())
        assert (meta["sampler"], meta["steps"]) == expected


def test_source_features_have_one_frame_per_joint_frame():
    m = load_motion("example:wave-both-hands")
    assert len(source_features(m, HUMANML3D, 20.0)) == len(m.joints)


def test_timeline_with_seconds_is_an_error(tmp_path, capsys):
    assert main(["generate", "--timeline", "walk:3; wave:2", "--seconds", "10", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("smf: error: --seconds does not apply to --timeline") and err.count("\n") == 1


def test_two_runs_into_one_folder_do_not_overwrite(tmp_path, capsys):
    args = ["generate", "a person walks", "--seconds", "2", "--steps", "2", "--format", "npy", "--out", str(tmp_path)]
    assert main(args) == 0 and main(args) == 0
    assert len(list(tmp_path.glob("*_joints.npy"))) == 2
    assert main(args + ["--overwrite"]) == 0
    assert len(list(tmp_path.glob("*_joints.npy"))) == 2


def test_long_timelines_and_edits_show_progress(pipe, capsys):
    pipe.timeline([("a person walks", 12.0), ("a person waves", 10.0)], steps=2, seed=0, progress=None)
    assert "timeline" in capsys.readouterr().err
    src = source_features(load_motion("example:wave-both-hands"), HUMANML3D, 20.0)
    pipe.edit("a person waves", src, "upper-body", steps=2, seed=0)
    assert "denoise" in capsys.readouterr().err


def test_edit_errors_speak_seconds_and_point_to_timeline(pipe):
    src = source_features(load_motion("example:wave-both-hands"), HUMANML3D, 20.0)
    with pytest.raises(SMFError, match=r"an edit of 15 s .* --timeline"):
        pipe.edit("a person waves", src, "prefix", keep_start=1.0, seconds=15.0)


def test_edit_mode_errors_name_the_flag(tmp_path, capsys):
    assert main(["edit", "x", "--motion", "example:wave-both-hands", "--mode", "prefix", "--keep-end", "1",
                 "--out", str(tmp_path)]) == 2
    assert "needs --keep-start" in capsys.readouterr().err
    assert main(["edit", "x", "--motion", "example:wave-both-hands", "--mode", "suffix", "--out", str(tmp_path)]) == 2
    assert "needs --keep-end" in capsys.readouterr().err


def test_raw_mocap_bvh_through_a_joint_map(bandai_mini_source, tmp_path, capsys):
    raw = next(bandai_mini_source.rglob("dataset-2_wave-left-hand_active_001.bvh"))
    assert main(["convert", str(raw), str(tmp_path / "j.npy"), "--to", "joints"]) == 2
    assert "--joint-map" in capsys.readouterr().err
    assert main(["convert", str(raw), str(tmp_path / "j.npy"), "--to", "joints", "--joint-map", "bandai-namco"]) == 0
    assert np.load(tmp_path / "j.npy").shape[1:] == (22, 3)
    assert main(["edit", "a person waves", "--motion", str(raw), "--joint-map", "bandai-namco", "--mode",
                 "prefix", "--keep-start", "1", "--seconds", "4", "--steps", "2", "--format", "npy",
                 "--out", str(tmp_path / "o")]) == 0
    assert len(np.load(next((tmp_path / "o").glob("*_joints.npy")))) == 80


def test_threads_default_to_the_idle_cores(monkeypatch):
    """`smf generate/edit` use --threads, else OMP_NUM_THREADS, else the cores less the load average (>= 1)."""
    import argparse
    import os

    import torch

    from stablemofusion.cli.options import idle_threads, set_threads
    from stablemofusion.core.errors import SMFError

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    for load, want in ((0.0, 4), (0.4, 4), (1.0, 3), (2.6, 1), (9.0, 1)):
        monkeypatch.setattr(os, "getloadavg", lambda load=load: (load, load, load))
        assert idle_threads() == want, load
    before = torch.get_num_threads()
    try:
        monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
        monkeypatch.setattr(os, "getloadavg", lambda: (3.0, 3.0, 3.0))
        set_threads(argparse.Namespace(threads=None))
        assert torch.get_num_threads() == 1  # one idle core of four
        set_threads(argparse.Namespace(threads=3))
        assert torch.get_num_threads() == 3
        monkeypatch.setenv("OMP_NUM_THREADS", "2")
        set_threads(argparse.Namespace(threads=None))
        assert torch.get_num_threads() == 3  # the user's OMP_NUM_THREADS: left alone
        with pytest.raises(SMFError, match="--threads must be at least 1"):
            set_threads(argparse.Namespace(threads=0))
    finally:
        torch.set_num_threads(before)


def test_a_prompts_file_is_written_batch_by_batch_as_one_call_makes_it(tmp_path, capsys):
    """Each batch's files are written before the next batch is made, numbered in file order, with the motions one
    library call of all the prompts makes (batch k: seed + k)."""
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    prompts = ["a person walks forward", "someone waves", "a man bows", "a person runs", "a woman jumps"]
    (tmp_path / "p.txt").write_text("\n".join(prompts) + "\n")
    out = tmp_path / "out"
    assert main(["generate", "--prompts", str(tmp_path / "p.txt"), "--batch-size", "2", "--seconds", "2",
                 "--seed", "5", "--format", "npy", "--out", str(out), "--engine", "onnx"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("wrote")]
    assert [ln.split(" (")[-1].split("seed ")[-1].rstrip(")") for ln in lines] == ["5", "5", "6", "6", "7"]
    files = sorted(out.glob("*_joints.npy"))
    assert [f.name[:3] for f in files] == ["000", "001", "002", "003", "004"]
    want = MotionPipeline.from_pretrained(backend="onnx", threads=1)(prompts, seconds=2, seed=5, batch_size=2)
    for f, w in zip(files, want):
        assert np.abs(np.load(f) - w.joints).max() < 1e-4  # the .npy holds float32 joints
