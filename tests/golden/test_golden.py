"""The same seed gives the same outputs as before the pipeline redesign (issue 26): text to motion, a timeline,
every edit mode and the HTTP response, against tests/golden/golden.npz (made by make_golden.py at 54506c9)."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from make_golden import http_body, outputs

GOLDEN = Path(__file__).resolve().parent / "golden.npz"


@pytest.fixture(scope="module")
def golden():
    with np.load(GOLDEN) as z:
        return {k: z[k] for k in z.files}


def test_pipeline_outputs_match_the_stored_ones(golden):
    from stablemofusion.pipeline import MotionPipeline

    torch.set_num_threads(1)
    new = outputs(MotionPipeline.from_pretrained(device="cpu"))
    assert set(new) == {k for k in golden if not k.startswith("http/")}
    for name, value in new.items():
        assert value.shape == golden[name].shape, name
        np.testing.assert_allclose(value, golden[name], rtol=1e-5, atol=1e-5, err_msg=name)


def test_http_response_matches_the_stored_one(golden):
    body = http_body()
    np.testing.assert_allclose(np.asarray(body.pop("joints"), dtype=np.float32), golden["http/joints"], atol=1e-5)
    assert json.loads(golden["http/meta"].tobytes()) == json.loads(json.dumps(body, sort_keys=True))
