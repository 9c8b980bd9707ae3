"""`POST /v1/generate` of a prompt that asks for one thing after another answers with both parts drawn, in order,
and says how the prompt was split."""

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
