"""A prompt that asks for one thing after another ("... then ...") is made as a timeline of its parts: in the
library on both backends and in `smf generate` (HTTP: tests/serve/test_sequences.py), each part drawn in its own
span, and the result says how the prompt was split."""

import json
import subprocess
import sys

import numpy as np
import pytest

from stablemofusion.core.sequence_plan import share_seconds, split_sequence
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

WALK_THEN_WAVE = "a tired man walks in a circle then waves"


@pytest.mark.parametrize("prompt,parts", [
    (WALK_THEN_WAVE, ["a tired man walks in a circle", "a tired man waves"]),
    ("a person bows and then runs forward", ["a person bows", "a person runs forward"]),
    ("a man runs forward, after that he bows", ["a man runs forward", "a man bows"]),
    ("someone raises both hands, then walks forward", ["someone raises both hands", "someone walks forward"]),
    ("an old man waves before walking away", ["an old man waves", "an old man walking away"]),
    ("turns left and then walks forward, then waves", ["turns left", "a person walks forward", "a person waves"]),
    ("a person waves both hands and smiles", ["a person waves both hands and smiles"]),
    ("a person walks forward", ["a person walks forward"]),
    ("a man walks then", ["a man walks then"]),
])
def test_a_prompt_is_split_at_its_sequence_words_with_the_first_subject(prompt, parts):
    assert split_sequence(prompt) == parts


def test_a_given_length_is_shared_in_proportion():
    assert share_seconds(6.0, [2.0, 4.0]) == [2.0, 4.0] and share_seconds(3.0, [2.0, 4.0]) == [1.0, 2.0]


def test_a_short_length_still_gives_every_part_the_shortest_segment_where_it_can():
    assert share_seconds(4.0, [3.0, 2.5], minimum=2.0) == [2.0, 2.0]
    assert share_seconds(5.0, [10.0, 1.0, 1.0], minimum=1.5) == [2.0, 1.5, 1.5]
    assert share_seconds(3.0, [3.0, 2.0], minimum=2.0) == [1.8, 1.2]  # too short for both: the caller refuses


def raised(joints: np.ndarray) -> np.ndarray:
    """(T,) whether a wrist is above its shoulder (HumanML3D joints: shoulders 16, 17; wrists 20, 21)."""
    return (joints[:, 20, 1] > joints[:, 16, 1]) | (joints[:, 21, 1] > joints[:, 17, 1])


@pytest.fixture(scope="module")
def onnx_pipe():
    return MotionPipeline.from_pretrained(backend="onnx", threads=1)


def test_both_parts_are_drawn_in_order_and_the_result_says_how(onnx_pipe):
    whole = onnx_pipe(WALK_THEN_WAVE, seed=0)[0]
    (walk, walk_s), (wave, wave_s) = whole.sequence
    assert (walk, wave) == ("a tired man walks in a circle", "a tired man waves")
    cut = int(round(walk_s * whole.fps))
    assert whole.frames == cut + int(round(wave_s * whole.fps))
    up = raised(whole.joints)
    assert up[:cut].mean() < 0.1 and up[cut:].mean() > 0.5  # the wave comes after the walk, where it was dropped
    travelled = np.linalg.norm(np.diff(whole.joints[:cut, 0, [0, 2]], axis=0), axis=1).sum()
    assert travelled > 2.0  # metres: the first part walks its circle
    given = onnx_pipe(WALK_THEN_WAVE, seconds=5, seed=0)[0]
    assert sum(s for _, s in given.sequence) == pytest.approx(5.0) and given.frames == 100


def test_the_torch_backend_splits_alike(onnx_pipe):
    a = onnx_pipe(WALK_THEN_WAVE, seed=3)[0]
    b = MotionPipeline.from_pretrained(device="cpu")(WALK_THEN_WAVE, seed=3, engine="eager")[0]
    assert a.sequence == b.sequence and np.abs(a.joints - b.joints).max() < 1e-3


def test_the_command_line_makes_the_parts_and_says_so(tmp_path):
    run = subprocess.run([sys.executable, "-m", "stablemofusion.cli.main", "generate", WALK_THEN_WAVE, "--seed", "0",
                          "--engine", "onnx", "--format", "npy,json", "--out", tmp_path], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "asks for one thing after another" in run.stderr and "'a tired man waves'" in run.stderr
    meta = json.loads(next(tmp_path.glob("*.json")).read_text())
    assert [p["prompt"] for p in meta["sequence"]] == ["a tired man walks in a circle", "a tired man waves"]
    joints = np.load(next(tmp_path.glob("*_joints.npy")))
    cut = int(round(meta["sequence"][0]["seconds"] * meta["fps"]))
    assert raised(joints)[cut:].mean() > 0.5


def test_a_prompt_that_is_one_of_the_models_actions_or_too_short_for_its_parts(onnx_pipe):
    """A prompt that is nearly one of the model's example sentences is that action, not split ("walks forward then
    turns left" is the corpus's walk-turn-left); "before" a noun is no sequence word; a length too short to give
    every part the model's shortest motion is one clear error."""
    from stablemofusion.core.errors import SMFError

    assert onnx_pipe("a person walks forward then turns left", seed=0)[0].sequence is None
    assert split_sequence("a person bows before the audience") == ["a person bows before the audience"]
    with pytest.raises(SMFError, match="need at least 2 s each"):
        onnx_pipe("a person bows and then runs forward", seconds=3, seed=0)


def test_an_explicit_path_gives_a_sequence_its_length(onnx_pipe):
    path = {"points": [[0, 0], [0, 4], [3, 4]], "times": [0, 4, 7]}
    r = onnx_pipe("a person walks then waves", path=path, seed=0)[0]
    assert len(r.sequence) == 2 and sum(s for _, s in r.sequence) == pytest.approx(7.0) and r.frames == 140


def test_what_a_pipeline_is_given_reaches_its_backend(onnx_pipe):
    from stablemofusion.core.errors import SMFError

    rigid = onnx_pipe.rigid
    onnx_pipe.rigid = rigid  # set on the backend, not on the pipeline
    assert "rigid" not in vars(onnx_pipe) and onnx_pipe.backend.rigid is rigid
    with pytest.raises(SMFError, match="--adapter needs PyTorch"):
        onnx_pipe.with_adapters([])
