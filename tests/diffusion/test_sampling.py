"""The sampling pieces: guidance wrappers, x0 hooks, noise, padding invariance, and the engines."""

import numpy as np
import pytest
import torch

from stablemofusion.diffusion.engine import FRAME_BUCKET, SolverEngine, batch_bucket
from stablemofusion.diffusion.sampling import Noise, Step, cfg_batched, cfg_two_pass, model_denoiser, \
    rescale_guidance, run_solver, with_x0_hook
from stablemofusion.diffusion.solvers import solver_table
from stablemofusion.models.registry import build_denoiser
from stablemofusion.models.presets import get_preset
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device (CUDA graphs)")


def _model(preset: str = "tiny"):
    torch.manual_seed(0)
    model = build_denoiser(get_preset(preset)).eval()
    with torch.no_grad():
        for p in model.parameters():
            if p.abs().sum() == 0:
                p.normal_(0, 0.02)
    return model


def _conditions(model, B: int = 2, L: int = 5, dtype: torch.dtype = torch.float32):
    g = torch.Generator().manual_seed(0)
    tokens = torch.randn(B, L, model.text_config.in_dim, generator=g).to(dtype)
    mask = torch.ones(B, L, dtype=torch.bool)
    mask[1, 3:] = False
    with torch.no_grad():
        cond = model.condition(tokens, mask, torch.zeros(B, dtype=torch.bool))
        uncond = model.condition(tokens, mask, torch.ones(B, dtype=torch.bool))
    return cond, uncond


def _guidance_case():
    """A float64 model, its conditions, a batch of 2 (the second padded after 20 of 32 frames) and one step."""
    model = _model().double()
    cond, uncond = _conditions(model, dtype=torch.float64)
    g = torch.Generator().manual_seed(1)
    x, mask = torch.randn(2, 32, 263, generator=g, dtype=torch.float64), torch.ones(2, 32, dtype=torch.bool)
    mask[1, 20:] = False
    return model, cond, uncond, x, mask, Step(0, 1, torch.tensor([700.0, 700.0], dtype=torch.float64))


@torch.no_grad()
def test_batched_guidance_equals_two_passes_and_the_model_forward():
    """Compared in float64: the batched and two-pass paths sum in different orders, and float32 kernels differ
    between CPUs by up to ~3e-4 here; in float64 they agree to ~1e-10 on any CPU."""
    model, cond, uncond, x, mask, step = _guidance_case()
    a = cfg_batched(model, cond, uncond, mask, 2.5)(x, step)
    b = cfg_two_pass(model_denoiser(model, cond, mask), model_denoiser(model, uncond, mask), 2.5)(x, step)
    assert a.dtype == torch.float64
    assert torch.allclose(a, b, rtol=0, atol=1e-8)
    # the split into condition() + denoise() is the same function as forward()
    g = torch.Generator().manual_seed(0)
    tokens = torch.randn(2, 5, model.text_config.in_dim, generator=g).double()
    tmask = cond.mask
    full = model(x, step.t, tokens, tmask, torch.zeros(2, dtype=torch.bool), mask)
    assert torch.allclose(full, model_denoiser(model, cond, mask)(x, step), rtol=0, atol=1e-8)


@torch.no_grad()
def test_guidance_rescale_matches_the_conditional_spread_over_valid_frames():
    """Share 1: each item's guided prediction takes the conditional one's standard deviation over its valid frames
    (padding ignored); share 0 and plain guidance are unchanged; both guidance paths rescale alike."""
    model, cond, uncond, x, mask, step = _guidance_case()
    c = model_denoiser(model, cond, mask)(x, step)
    plain = cfg_batched(model, cond, uncond, mask, 2.5)(x, step)
    full = cfg_batched(model, cond, uncond, mask, 2.5, rescale=1.0)(x, step)
    half = cfg_two_pass(model_denoiser(model, cond, mask), model_denoiser(model, uncond, mask), 2.5, mask, 0.5)(x, step)
    for i, n in enumerate((32, 20)):
        assert torch.allclose(full[i, :n].std(unbiased=False), c[i, :n].std(unbiased=False), rtol=1e-10, atol=0)
        assert not torch.allclose(plain[i, :n].std(unbiased=False), c[i, :n].std(unbiased=False), rtol=1e-3, atol=0)
    assert torch.allclose(half, 0.5 * (plain + full), rtol=0, atol=1e-8)
    assert torch.equal(rescale_guidance(plain, c, mask, 0.0), plain)
    x[1, 20:] = 1e3  # what padded frames hold does not move the valid ones
    again = cfg_batched(model, cond, uncond, mask, 2.5, rescale=1.0)(x, step)
    assert torch.allclose(again[1, :20], full[1, :20], rtol=0, atol=1e-8)


def test_x0_hooks_see_every_step_once_in_order():
    seen = []

    def hook(x0, step):
        seen.append((step.index, step.count))
        return x0 * 0.5

    table = solver_table("dpmsolver++-karras", 6)
    out = run_solver(with_x0_hook(lambda x, s: torch.ones_like(x), hook), table, torch.zeros(1, 4, 2), None)
    assert seen == [(k, 6) for k in range(6)]
    assert torch.allclose(out, torch.full_like(out, 0.5), atol=1e-5)  # the last step returns the hooked x0


def test_per_item_noise_does_not_depend_on_the_batch():
    dev = torch.device("cpu")
    alone = Noise([7], [30], 5, dev)
    batched = Noise([3, 7], [50, 30], 5, dev)
    assert torch.equal(alone.draw()[0], batched.draw()[1, :30])
    assert torch.equal(alone.draw(4)[:, 0], batched.draw(4)[:, 1, :30])
    assert batched.draw(2)[:, 1, 30:].abs().sum() == 0


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=cuda)])
@pytest.mark.parametrize("seed", [5, [5, 6]])
def test_step_noise_generators_live_on_the_sampling_device(device, seed):
    """Schedulers that draw their own noise (lcm's eager loop) get generators on the noise's device, seeded
    from the call's seed (on CUDA a seed drawn with a CUDA generator on the CPU failed)."""
    gens = Noise(seed, [30, 20][: len(seed) if isinstance(seed, list) else 1], 5, torch.device(device)).generator()
    gens = gens if isinstance(gens, list) else [gens]
    assert all(g.device.type == device for g in gens)
    again = Noise(seed, [30, 20][: len(gens)], 5, torch.device(device)).generator()
    again = again if isinstance(again, list) else [again]
    assert [g.initial_seed() for g in gens] == [g.initial_seed() for g in again]


@pytest.mark.parametrize("preset", ["tiny", "dit", "retnet"])
@torch.no_grad()
def test_padding_to_a_length_bucket_leaves_valid_frames_unchanged(preset):
    """The engine pads lengths up to multiples of 16 only where that cannot change the result."""
    model = _model(preset)
    cond, _ = _conditions(model)
    T = 37
    Tb = model.frame_bucket(T, FRAME_BUCKET)
    assert Tb == 48
    x = torch.randn(2, T, 263)
    t = torch.tensor([500.0, 20.0])
    mask = torch.ones(2, T, dtype=torch.bool)
    mask[1, 30:] = False
    ref = model.denoise(x, t, cond, mask)
    pad_x = torch.cat([x, torch.randn(2, Tb - T, 263)], 1)
    pad_mask = torch.cat([mask, torch.zeros(2, Tb - T, dtype=torch.bool)], 1)
    out = model.denoise(pad_x, t, cond, pad_mask)[:, :T]
    assert torch.allclose(out[0], ref[0], atol=1e-5) and torch.allclose(out[1, :30], ref[1, :30], atol=1e-5)


def test_unmasked_models_are_not_padded():
    model = build_denoiser(get_preset("unet-baseline"))
    assert not model.padding_invariant and model.frame_bucket(37, FRAME_BUCKET) == 37


def test_batch_buckets():
    assert [batch_bucket(n) for n in (1, 2, 3, 5, 17, 32, 40)] == [1, 2, 4, 8, 32, 32, 40]


@pytest.fixture(scope="module")
def pipe(tmp_path_factory, save_tiny_checkpoint):
    path = save_tiny_checkpoint(tmp_path_factory.mktemp("ckpt") / "c", np.zeros(263), np.full(263, 0.1))
    return MotionPipeline.from_pretrained(path, device="cpu")


@pytest.mark.parametrize("sampler", ["sde-dpmsolver++-karras", "dpmsolver++", "ddim", "euler-karras"])
def test_fast_engine_equals_the_diffusers_loop(pipe, sampler):
    prompts, lengths = ["a person walks forward", "a person waves"], [48, 40]
    a = pipe.denoise(prompts, lengths, sampler=sampler, steps=8, seed=[1, 2], engine="eager")
    b = pipe.denoise(prompts, lengths, sampler=sampler, steps=8, seed=[1, 2], engine="fast")
    assert torch.allclose(a, b, atol=1e-4 * float(pipe.std.max()) * 10), float((a - b).abs().max())


def test_auto_engine_is_fast_on_cpu_and_eager_for_other_samplers(pipe):
    assert pipe.engine_for("sde-dpmsolver++-karras", "auto") == "fast"
    assert pipe.engine_for("pndm", "auto") == "eager"


def test_compiled_engine_equals_the_fast_one(pipe):
    """Inductor on the CPU (about 40 s of compilation on a 2-core CPU): padded to the 48-frame bucket."""
    prompts, lengths = ["a person walks forward"], [37]
    a = pipe.denoise(prompts, lengths, steps=4, seed=[1], engine="fast")
    b = pipe.denoise(prompts, lengths, steps=4, seed=[1], engine="compiled")
    assert b.shape == a.shape and torch.allclose(a, b, atol=1e-4)


@cuda
@pytest.mark.parametrize("engine", ["compiled", "graph", "compiled-graph"])
def test_cuda_engines_equal_the_fast_one(tmp_path, save_tiny_checkpoint, engine):
    path = save_tiny_checkpoint(tmp_path / "c", np.zeros(263), np.full(263, 0.1))
    p = MotionPipeline.from_pretrained(path, device="cuda", dtype=torch.float32)
    prompts, lengths = ["a person walks forward", "a person waves", "a person bows"], [40, 57, 196]
    a = p.denoise(prompts, lengths, steps=10, seed=[1, 2, 3], engine="fast")
    b = p.denoise(prompts, lengths, steps=10, seed=[1, 2, 3], engine=engine)
    c = p.denoise(prompts, lengths, steps=10, seed=[1, 2, 3], engine=engine)  # replay of the cached graph
    # 4e-3: on an H100 cuDNN's TF32 convolutions make even the diffusers loop differ from the fast
    # one by up to 1.6e-3 after 10 SDE steps (values up to 0.08); compiled 1.5e-3; graph replays fast exactly
    assert torch.allclose(a, b, atol=4e-3) and torch.equal(b, c)
    d = p.denoise(prompts[:1], lengths[:1], steps=10, seed=[1], engine=engine)  # another batch bucket
    assert torch.allclose(d[0, :40], b[0, :40], atol=4e-3)


@cuda
def test_graph_engine_reports_its_capture_cost(tmp_path, save_tiny_checkpoint):
    path = save_tiny_checkpoint(tmp_path / "c", np.zeros(263), np.full(263, 0.1))
    p = MotionPipeline.from_pretrained(path, device="cuda")
    p.denoise(["a person walks forward"], [60], steps=10, seed=0, engine="graph")
    engine = p.solver_engine("graph")
    assert isinstance(engine, SolverEngine) and len(engine.stats.warmup_seconds) == 1
