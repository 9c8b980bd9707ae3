"""One set of rules: the same request gets the same answer from the library, `smf generate` and the HTTP API (the
viewer sends its requests to the HTTP API as they are and shows its answer: tests/serve/test_viewer.py)."""

from __future__ import annotations

import numpy as np
import pytest

from stablemofusion.core import limits
from stablemofusion.cli.main import main
from stablemofusion.core.errors import SMFError
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve import create_app

from serve.serve_helpers import call

# (request, expected): frames of the motion, or a piece of the one-line refusal
TABLE = [
    ({"seconds": 30}, 600),  # longer than the model's window: made window by window, at every door
    ({"seconds": 2, "guidance": -3}, "guidance must be a number from 0 to 20"),
    ({"seconds": 2, "steps": 0}, "steps must be a whole number from 1 to 50"),
    ({"seconds": 2, "steps": 50}, 40),
    ({"seconds": 121}, "seconds must be more than 0 and at most 120 s"),
    ({"seconds": 2, "seed": -1}, "seed must be a whole number"),
]
PROMPT = "a person walks forward"


def library(pipe, req: dict):
    kw = {"seconds": req["seconds"], "seed": req.get("seed", 0), "guidance_scale": req.get("guidance"),
          "steps": req.get("steps", 1)}
    try:
        return len(pipe([PROMPT], **kw)[0].joints)
    except SMFError as e:
        return str(e)


def http(pipe, req: dict):
    (r,) = call(create_app(pipe), ("POST", "/v1/generate", {"prompt": PROMPT, "seed": 0, "steps": 1, **req}))
    if r.status_code == 200:
        return r.json()["frames"]
    assert r.status_code == 422, r.text
    return r.json()["error"]


def cli(checkpoint, req: dict, tmp_path, capsys):
    args = ["generate", PROMPT, "--checkpoint", str(checkpoint), "--out", str(tmp_path), "--format", "npy",
            "--seconds", str(req["seconds"]), "--seed", str(req.get("seed", 0)), "--steps", str(req.get("steps", 1))]
    if "guidance" in req:
        args += ["--guidance", str(req["guidance"])]
    capsys.readouterr()
    code = main(args)
    out, err = capsys.readouterr()
    if code == 0:
        return len(np.load(next(tmp_path.glob("*_joints.npy"))))
    assert code == 2 and err.count("\n") == 1 and err.startswith("smf: error: "), err
    return err


@pytest.mark.parametrize("req, expected", TABLE)
def test_every_door_answers_a_request_alike(pipe, checkpoint, req, expected, tmp_path, capsys):
    answers = {"library": library(pipe, req), "http": http(pipe, req), "cli": cli(checkpoint, req, tmp_path, capsys)}
    for door, got in answers.items():
        if isinstance(expected, int):
            assert got == expected, (door, got)
        else:
            assert isinstance(got, str) and expected in got, (door, got)


def test_the_limits_table_is_served_for_the_viewer(pipe):
    (r,) = call(create_app(pipe), ("GET", "/v1/health", None))
    assert r.json()["limits"] == limits.table()
    assert limits.table()["seconds"] == [0, limits.MAX_SECONDS]


@pytest.mark.parametrize("check, bad", [
    (limits.check_steps, [0, 51, 2.0, True]),
    (limits.check_guidance, [-0.1, 20.5, float("nan"), float("inf"), "2"]),
    (limits.check_seconds, [0, -1, 120.01, float("nan")]),
    (limits.check_seed, [-1, 2**53, 1.5]),
    (limits.check_batch_size, [0, limits.MAX_BATCH_SIZE + 1]),
])
def test_each_limit_refuses_what_is_outside_it(check, bad):
    for value in bad:
        with pytest.raises(SMFError):
            check(value)


def test_one_seed_policy():
    assert limits.base_seed(7) == 7
    seeds = {limits.base_seed(None) for _ in range(20)}
    assert len(seeds) > 1 and all(0 <= s < limits.SEED_RANGE for s in seeds)


@pytest.fixture(scope="module")
def student(checkpoint, tmp_path_factory, save_tiny_student):
    return save_tiny_student(tmp_path_factory.mktemp("limits-student") / "student", checkpoint)


def test_a_student_takes_only_the_steps_it_samples_soundly(student, tmp_path, capsys):
    """Past STUDENT_MAX_STEPS a distilled student drifts into motions no human makes: refused at every door."""
    pipe = MotionPipeline.from_pretrained(student, device="cpu")
    assert pipe.student and pipe.max_steps == limits.STUDENT_MAX_STEPS
    assert len(pipe([PROMPT], seconds=2, seed=0, steps=limits.STUDENT_MAX_STEPS)[0].joints) == 40
    req = {"seconds": 2, "steps": limits.STUDENT_MAX_STEPS + 1}
    answers = [library(pipe, req), http(pipe, req), cli(student, req, tmp_path, capsys)]
    assert all(isinstance(a, str) and f"steps must be at most {limits.STUDENT_MAX_STEPS}" in a for a in answers)
