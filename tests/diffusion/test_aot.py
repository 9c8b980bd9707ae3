"""The ``aot`` engine: model.denoise exported and compiled ahead of time (AOTInductor) into a cached package.

Builds one package for the tiny model (about 30-60 s on a 2-core CPU, once for the module); skipped where
torch has no AOTInductor or no C++ compiler is installed."""

import os
import shutil

import numpy as np
import pytest
import torch

from stablemofusion.core.errors import SMFError
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

_cxx = os.environ.get("CXX", "g++")
pytestmark = [
    pytest.mark.skipif(not hasattr(torch._inductor, "aoti_compile_and_package"),
                       reason="this torch has no AOTInductor (torch._inductor.aoti_compile_and_package)"),
    pytest.mark.skipif(shutil.which(_cxx) is None and shutil.which("c++") is None,
                       reason="AOTInductor needs a C++ compiler (g++ / c++) and none is on PATH"),
]


@pytest.fixture(scope="module")
def aot_pipe(tmp_path_factory, save_tiny_checkpoint):
    cache = tmp_path_factory.mktemp("aot-cache")
    old = os.environ.get("SMF_AOT_CACHE")
    os.environ["SMF_AOT_CACHE"] = str(cache)
    path = save_tiny_checkpoint(tmp_path_factory.mktemp("tiny") / "c", np.zeros(263), np.full(263, 0.1))
    yield MotionPipeline.from_pretrained(path, device="cpu", dtype=torch.float32), cache
    if old is None:
        os.environ.pop("SMF_AOT_CACHE", None)
    else:
        os.environ["SMF_AOT_CACHE"] = old


def test_aot_engine_equals_eager_for_any_batch_and_length(aot_pipe):
    pipe, cache = aot_pipe
    prompts, lengths = ["a person walks forward", "a person waves", "a person bows"], [40, 57, 196]
    eager = pipe.denoise(prompts, lengths, steps=4, seed=[1, 2, 3], engine="eager")
    fast = pipe.denoise(prompts, lengths, steps=4, seed=[1, 2, 3], engine="fast")
    aot = pipe.denoise(prompts, lengths, steps=4, seed=[1, 2, 3], engine="aot")
    assert aot.shape == eager.shape
    assert (aot - eager).abs().max() < 1e-4 and (aot - fast).abs().max() < 1e-4
    # one package for every shape: another batch size, length and prompt length reuse it (no rebuild)
    one = pipe.denoise(["a person jumps up and down twice, then sits on the floor"], [83], steps=4, seed=[5],
                       engine="aot")
    ref = pipe.denoise(["a person jumps up and down twice, then sits on the floor"], [83], steps=4, seed=[5],
                       engine="eager")
    assert (one - ref).abs().max() < 1e-4
    stats = pipe.solver_engine("aot").stats.warmup_seconds
    assert list(stats) == [("aot", "built")]
    assert len(list(cache.glob("denoise-*.pt2"))) == 1


def test_aot_package_is_loaded_not_rebuilt_and_keyed_by_the_weights(aot_pipe):
    from stablemofusion.diffusion import aot

    pipe, cache = aot_pipe
    pipe.denoise(["a person walks"], [40], steps=2, seed=0, engine="aot")  # built (or reused) by this module
    aot._LOADED.clear()  # as in a new process
    again = aot.AOTDenoise(pipe.model)
    assert not again.built and again.path.exists()
    assert aot.artefact_exists(pipe.model)
    model = pipe.model
    key = aot.artefact_key(model, torch.device("cpu"), torch.float32)
    with torch.no_grad():
        p = next(model.parameters())
        saved = p.clone()
        p.add_(1.0)
        try:
            assert aot.artefact_key(model, torch.device("cpu"), torch.float32) != key
        finally:
            p.copy_(saved)
    assert aot.artefact_key(model, torch.device("cpu"), torch.float32) == key


def test_aot_engine_rejects_models_it_cannot_pad():
    from stablemofusion.diffusion.aot import check_model

    class NotPaddable(torch.nn.Module):
        motion_dim = 263
        padding_invariant = False

    with pytest.raises(SMFError, match="padding"):
        check_model(NotPaddable())
