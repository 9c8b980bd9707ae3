"""What an HTTP answer tells the user: a prompt that asks for one thing after another answers with both parts drawn,
in order, and says how it was split; every answer carries its warnings."""

import numpy as np

from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve import create_app

from serve_helpers import call

WALK_THEN_WAVE = "a tired man walks in a circle then waves"


def raised(joints: np.ndarray) -> np.ndarray:
    """(T,) whether a wrist is above its shoulder (HumanML3D joints: shoulders 16, 17; wrists 20, 21)."""
    return (joints[:, 20, 1] > joints[:, 16, 1]) | (joints[:, 21, 1] > joints[:, 17, 1])


def test_the_http_answer_holds_the_parts():
    onnx_pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    (r,) = call(create_app(onnx_pipe, max_streams=0), ("POST", "/v1/generate", {"prompt": WALK_THEN_WAVE, "seed": 0}))
    assert r.status_code == 200, r.text
    body = r.json()
    assert [p["prompt"] for p in body["sequence"]] == ["a tired man walks in a circle", "a tired man waves"]
    cut = int(round(body["sequence"][0]["seconds"] * body["fps"]))
    assert raised(np.asarray(body["joints"]))[cut:].mean() > 0.5


def test_every_answer_carries_its_warnings():
    """What the command line prints on stderr reaches an HTTP client too: a length clamped to the model's range, a
    prompt out of domain; a plain request has none."""
    onnx_pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    short, far, plain = call(create_app(onnx_pipe, max_streams=0),
                             ("POST", "/v1/generate", {"prompt": "a person walks", "seconds": 1, "seed": 0}),
                             ("POST", "/v1/generate", {"prompt": "a person jumps", "seconds": 3, "seed": 0}),
                             ("POST", "/v1/generate", {"prompt": "a person walks", "seconds": 3, "seed": 0}))
    assert short.json()["warnings"] == ["length 20 frames (1.00 s) clamped to 40 frames (2.00 s), the range this "
                                        "model was trained on"]
    assert len(far.json()["warnings"]) == 1 and "not like anything this model was trained on" in far.json()["warnings"][0]
    assert "warnings" not in plain.json()
