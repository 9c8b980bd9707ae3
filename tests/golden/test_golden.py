"""The same seed gives the same outputs as when the 1-step student became the default model: the teacher
(``default_model/teacher``, 10 steps) on text to motion, a timeline, every edit mode and the HTTP response, and the
student on a few of them, against tests/golden/golden.npz (made by make_golden.py at the commit its docstring
names). Any change of what the shipped pair generates (weights, samplers, editing, the rigid stage, the server's
body) shows here; a deliberate one regenerates the file and says so in the commit.

Tolerance 1e-4: a prompt equal to an example sentence of the known actions ("a person walks forward") is encoded
in its own batch; MiniLM's float noise between batch shapes moves a few features by up to 3.5e-5 (and may differ
between machines). Any change of behaviour moves them by far more."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from make_golden import http_body, outputs, student_outputs

GOLDEN = Path(__file__).resolve().parent / "golden.npz"
TOL = 1e-4


@pytest.fixture(scope="module")
def golden():
    with np.load(GOLDEN) as z:
        return {k: z[k] for k in z.files}


def _compare(new: dict, stored: dict) -> None:
    assert set(new) == set(stored)
    for name, value in new.items():
        assert value.shape == stored[name].shape, name
        np.testing.assert_allclose(value, stored[name], rtol=TOL, atol=TOL, err_msg=name)


def test_teacher_outputs_match_the_stored_ones(golden):
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    torch.set_num_threads(1)
    new = outputs(MotionPipeline.from_pretrained(teacher=True, device="cpu"))
    _compare(new, {k: v for k, v in golden.items() if not k.startswith(("student/", "http/"))})


def test_student_outputs_match_the_stored_ones(golden):
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    torch.set_num_threads(1)
    new = student_outputs(MotionPipeline.from_pretrained(device="cpu"))
    _compare(new, {k: v for k, v in golden.items() if k.startswith("student/") and not k.startswith("student/http/")})


def test_http_response_matches_the_stored_one(golden):
    body = http_body(teacher=True)
    np.testing.assert_allclose(np.asarray(body.pop("joints"), dtype=np.float32), golden["http/joints"], atol=TOL)
    for made_by in ("smf_version", "model_version"):  # what made it, which moves with each version (test_version.py)
        body.pop(made_by)
    before = json.loads(golden["http/meta"].tobytes())
    assert body.pop("similarity") == pytest.approx(before.pop("similarity"), abs=TOL)  # the detector's score
    assert before == json.loads(json.dumps(body, sort_keys=True))


def test_http_response_of_the_student_matches_the_stored_one(golden):
    body = http_body()
    np.testing.assert_allclose(np.asarray(body["joints"], dtype=np.float32), golden["student/http/joints"], atol=TOL)
