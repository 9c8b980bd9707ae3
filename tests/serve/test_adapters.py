"""Serving adapters beside the model: requests name one, requests of different adapters are generated apart."""

from __future__ import annotations

import numpy as np
import pytest

from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve import create_app

from serve_helpers import call


@pytest.fixture(scope="module")
def served(checkpoint, save_random_adapter, tmp_path_factory):
    """The tiny model with two adapters offered beside it, and the adapter files."""
    folder = tmp_path_factory.mktemp("adapters")
    files = [save_random_adapter(folder / f"{n}.safetensors", checkpoint, n, seed=s) for n, s in (("kick", 1), ("hop", 2))]
    pipe = MotionPipeline.from_pretrained(checkpoint, device="cpu")
    pipe.add_variants(files)
    return pipe, files


def test_requests_of_different_adapters_are_batched_apart_and_get_their_own_motion(served):
    pipe, files = served
    app = create_app(pipe, wait_ms=300)
    reqs = [(None, 3), ("kick", 3), ("hop", 3), (None, 4), ("kick", 5)]
    out = call(app, *[("POST", "/v1/generate", {"prompt": "a person kicks", "seconds": 2.0, "seed": seed, "steps": 2,
                                                **({} if a is None else {"adapter": a})}) for a, seed in reqs])
    assert [r.status_code for r in out] == [200] * 5
    assert sorted(app.state.batcher.batch_sizes) == [1, 2, 2]  # one call per model
    models = {None: MotionPipeline.from_pretrained(pipe.path, device="cpu")}
    models.update({n: models[None].with_adapters([f]) for n, f in zip(("kick", "hop"), files)})
    for r, (a, seed) in zip(out, reqs):
        alone = models[a](["a person kicks"], seconds=2.0, seed=[seed], steps=2)[0]
        assert np.abs(np.asarray(r.json()["joints"]) - alone.joints).max() < 1e-4
    base, kick = out[0].json()["joints"], out[1].json()["joints"]
    assert np.abs(np.asarray(base) - np.asarray(kick)).max() > 1e-3  # same seed, another model


def test_health_lists_the_adapters_and_an_unknown_one_is_a_422(served):
    pipe, _ = served
    app = create_app(pipe)
    health, bad = call(app, ("GET", "/v1/health", None),
                       ("POST", "/v1/generate", {"prompt": "a person kicks", "adapter": "dance"}))
    assert health.json()["adapters"] == ["kick", "hop"]
    assert bad.status_code == 422 and "no adapter named 'dance'" in bad.json()["error"]
