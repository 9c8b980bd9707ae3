"""The JavaScript runtime (runtime/smf.js of a site folder) run by Node.js on the vendored ONNX Runtime Web: the
Python runtime's joints for the same prompt, seed and length. Skipped where Node.js is absent (CI has it)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from stablemofusion.core.sequence_plan import share_seconds, split_sequence
from stablemofusion.core.timeline_plan import DEFAULT_OVERLAP, plan_windows
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve.site import write_site

NODE = shutil.which("node")
# one prompt of 300 characters (no sequence words: those make a timeline, tested below)
LONG_PROMPT = ("a tired old man in a heavy winter coat walks slowly forward along a quiet street, stops for a moment "
               "to catch his breath, looks around at the houses and the trees on both sides, and raises his right "
               "hand to wave at a neighbour across the road and carries on walking with small careful steps home, now")
pytestmark = pytest.mark.skipif(NODE is None, reason="Node.js is not installed (apt-get install nodejs)")


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    return write_site(tmp_path_factory.mktemp("site") / "site", pipe.graphs), pipe


def node_generate(folder, *args) -> subprocess.CompletedProcess:
    return subprocess.run([NODE, str(folder / "runtime" / "generate.mjs"), *map(str, args)], capture_output=True,
                          text=True, timeout=300)


@pytest.mark.parametrize("prompt, seconds, seed, footskate", [("a person waves both hands happily", 4, 7, "off"),
                                                              ("a person waves both hands happily", 4, 7, "post"),
                                                              ("an old man walks forward slowly", 6.3, 123456789012, "post"),
                                                              ("a person runs forward", 3, 5, "post"),
                                                              ("someone bows politely", None, 0, "off"),
                                                              ("a man walks in a circle", None, 3, "post"),
                                                              ("a child runs zigzagging forward", None, 3, "post"),
                                                              ("an old woman turns 45 degrees to the right", 3, 1, "off"),
                                                              ("a person walks forward and comes back", None, 2, "post"),
                                                              ("a man walks sideways to the left", None, 4, "post"),
                                                              ("a woman walks and turns left", 4, 5, "post"),
                                                              ("someone walks along a curve to the right", None, 6, "post"),
                                                              (LONG_PROMPT, None, 8, "post"),
                                                              ("a tired man walks in a circle then waves", None, 0, "post"),
                                                              ("a person bows and then runs forward", 7, 3, "off"),
                                                              ("someone raises both hands, then walks forward and then "
                                                               "turns left", None, 11, "post")])
def test_node_reproduces_the_python_runtime(site, prompt, seconds, seed, footskate):
    """Text, path words, sampling, decoding, the rigid stage and the final stage (contacts, holds, the lean, the
    legs' IK): the Python runtime's joints. A prompt that asks for one thing after another is a timeline of its parts
    in JavaScript too: the same parts, lengths, windows (each continuing the last through continue.onnx) and path
    words per part."""
    folder, pipe = site
    extra = [] if seconds is None else ["--seconds", seconds]
    run = node_generate(folder, prompt, *extra, "--seed", seed, "--footskate", footskate)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout)
    want = pipe(prompt, seconds=seconds, seed=seed, footskate=footskate)[0]
    joints = np.asarray(got["joints"])
    assert joints.shape == want.joints.shape  # the length model's length too, where none is given
    assert np.abs(joints - want.joints).max() < 5e-6  # metres: 0.2-1.3 um seen (the graphs' float32 differ)
    assert [p for p, _ in got.get("sequence", [])] == [p for p, _ in want.sequence or []]
    assert np.allclose([s for _, s in got.get("sequence", [])], [s for _, s in want.sequence or []], rtol=0, atol=1e-9)
    assert got["outOfDomain"] == want.domain.out_of_domain
    assert [c[0] for c in got["closest"]] == [c[0] for c in want.domain.closest]
    assert abs(got["similarity"] - want.domain.similarity) < 1e-4


SEQUENCE_SPLITS = ["a man runs forward, after that he bows", "an old man waves before walking away",
                   "turns left and then walks forward, then waves", "a person waves both hands and smiles",
                   "a man walks then", "a woman bows, and then to wave", "She jumps and afterwards she sits down",
                   "one two then three then four then five then six then seven then eight then nine"]


def test_node_splits_and_plans_sequences_as_the_python_does(site):
    """splitSequence, shareSeconds and planWindows (sequence.js) give the Python's answers (split_sequence,
    share_seconds, plan_windows) on every benchmark prompt and on awkward ones."""
    folder, pipe = site
    bench = Path(__file__).resolve().parents[2] / "benchmarks"
    prompts = [json.loads(line)["prompt"] for name in ("prompts_sequences.jsonl", "prompts_plain.jsonl")
               for line in (bench / name).read_text(encoding="utf-8").splitlines() if line] + SEQUENCE_SPLITS
    shares = [(6.0, [2.0, 4.0], 0.0), (4.0, [3.0, 2.5], 2.0), (5.0, [10.0, 1.0, 1.0], 1.5), (3.0, [3.0, 2.0], 2.0),
              (7.3, [1.1, 2.9, 4.05], 2.0)]
    timelines = [[("a", 60), ("b", 300)], [("a", 10), ("b", 41), ("c", 180)], [("a", 196)]]
    script = ("import { splitSequence, shareSeconds, planWindows, roundHalfEven } from './runtime/sequence.js';\n"
              "import { readFileSync } from 'node:fs';\n"
              "const info = JSON.parse(readFileSync('./model/web.json', 'utf8'));\n"
              "const [prompts, shares, timelines] = JSON.parse(readFileSync(0, 'utf8'));\n"
              "console.log(JSON.stringify([prompts.map((p) => splitSequence(p, info.sequence)),\n"
              "  shares.map(([t, own, m]) => shareSeconds(t, own, m)),\n"
              "  timelines.map((s) => planWindows(s, info.max_frames, info.sequence.overlap_frames, info.sequence.tail)),\n"
              "  [0.5, 1.5, 2.5, 2.4999, 40.5, 41.5].map(roundHalfEven)]));\n")
    (folder / "seq.mjs").write_text(script)
    run = subprocess.run([NODE, str(folder / "seq.mjs")], input=json.dumps([prompts, shares, timelines]),
                         capture_output=True, text=True, timeout=120, cwd=folder)
    assert run.returncode == 0, run.stderr
    splits, shared, windows, rounded = json.loads(run.stdout)
    assert splits == [split_sequence(p) for p in prompts]
    assert sum(len(s) > 1 for s in splits) >= 12  # the benchmark's ten and the awkward ones do split
    for got, (total, own, minimum) in zip(shared, shares):
        assert np.allclose(got, share_seconds(total, own, minimum), rtol=0, atol=1e-12)
    info = json.loads((folder / "model" / "web.json").read_text())
    for got, segments in zip(windows, timelines):
        want = plan_windows(segments, info["max_frames"], int(round(DEFAULT_OVERLAP * info["fps"])), info["min_frames"])
        assert got == [{"prompt": w.prompt, "keep": w.keep, "new": w.new, "segment": w.segment, "tail": w.tail}
                       for w in want]
    assert rounded == [round(x) for x in (0.5, 1.5, 2.5, 2.4999, 40.5, 41.5)]


def test_node_gives_one_clear_error_for_bad_input(site):
    folder, _ = site
    for args, why in [(["", "--seed", "1"], "prompt"), (["a person walks", "--seed", "-3"], "seed"),
                      (["a person walks", "--seconds", "30"], "at most"),
                      (["a person bows and then runs forward", "--seconds", "3"], "too short for them"),
                      (["a person bows and then runs forward", "--seconds", "500"], "at most 120 s"),
                      (["a person walks", "--footskate", "loop"], "footskate"),
                      (["a person walks", "--path", "[[0, 0]]"], "2 to 256"),
                      (["a person walks", "--path", "[[1e15, 0], [1e15, 3]]"], "within 200 m of the origin"),
                      (["a person walks", "--path", '{"points": [[0, 0], [0, 3]], "times": [0, 1e-9]}'],
                       "at most 12 m/s")]:
        run = node_generate(folder, *args)
        assert run.returncode == 2 and why in run.stderr and len(run.stderr.strip().splitlines()) == 1, run.stderr


@pytest.mark.parametrize("prompt, path, footskate", [
    ("a person walks", [[1, 0], [1, 3], [4, 3], [4, 0]], "post"),
    ("a person runs", {"points": [[0, 0], [0, 3], [3, 3]], "times": [0, 1.5, 3]}, "off")])
def test_node_follows_an_explicit_path_as_the_python_runtime(site, prompt, path, footskate):
    folder, pipe = site
    run = node_generate(folder, prompt, "--seed", 1, "--footskate", footskate, "--path", json.dumps(path))
    assert run.returncode == 0, run.stderr
    want = pipe(prompt, seed=1, footskate=footskate, path=path)[0].joints
    got = np.asarray(json.loads(run.stdout)["joints"])
    assert got.shape == want.shape and np.abs(got - want).max() < 5e-6


def test_node_tells_prompts_that_are_not_english_as_the_python_does(site):
    """The page's language check is the Python's rule on the Python's word lists (web.json): the same reason for
    every prompt of the foreign and English benchmark sets."""
    from stablemofusion.core.language import not_english

    folder, _ = site
    bench = Path(__file__).resolve().parents[2] / "benchmarks"
    prompts = [json.loads(line)["prompt"] for name in ("prompts_foreign.jsonl", "prompts_foreign_heldout.jsonl",
                                                      "prompts_plain.jsonl", "prompts_sequences.jsonl")
               for line in (bench / name).read_text(encoding="utf-8").splitlines() if line]
    script = ("import { notEnglish } from './runtime/smf.js';\nimport { readFileSync } from 'node:fs';\n"
              "const lex = JSON.parse(readFileSync('./model/web.json', 'utf8')).languages;\n"
              "const prompts = JSON.parse(readFileSync(0, 'utf8'));\n"
              "console.log(JSON.stringify(prompts.map((p) => notEnglish(p, lex))));\n")
    (folder / "lang.mjs").write_text(script)
    run = subprocess.run([NODE, str(folder / "lang.mjs")], input=json.dumps(prompts), capture_output=True, text=True,
                         timeout=120, cwd=folder)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout) == [not_english(p) for p in prompts]
    two = json.loads(node_generate(folder, "un homme marche lentement vers la porte", "--seconds", "3").stdout)
    assert "does not look like English (French words)" in two["warnings"][0]


def test_node_warns_of_actions_the_model_draws_badly_as_the_python_does(site):
    folder, pipe = site
    for prompt in ("a person kicks with the right leg", "someone slashes with a sword", "a person walks forward",
                   "a confident model struts down the runway"):  # closest to kick, but under the floor
        got = json.loads(node_generate(folder, prompt, "--seconds", "2", "--seed", "0").stdout)["warnings"]
        want = [w for w in pipe(prompt, seconds=2, seed=0)[0].warnings if "draws badly" in w]
        assert [w for w in got if "draws badly" in w] == [w.replace("'", '"') for w in want], prompt
        assert bool(want) == ("walks" not in prompt and "struts" not in prompt)  # kick and slash warned, walks not
