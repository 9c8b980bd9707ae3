"""CondUNet1D: shapes, zero init, padding invariance (GroupNorm tweak + masking), text padding, CFG drop, flags."""

from __future__ import annotations

import importlib.util
import json
import sys
import types
from dataclasses import asdict, replace

import pytest
import torch

from stablemofusion.models.base import ModelConfig, TextConfig
from stablemofusion.models.registry import build_denoiser
from stablemofusion.models.attention import CrossAttention
from stablemofusion.models.registry import build_denoiser
from stablemofusion.models.presets import get_preset
from stablemofusion.models.unet1d import CondUNet1D, FrameGroupNorm, UNetConfig

D = 11  # motion features
TEXT = TextConfig(in_dim=12, latent=16, layers=1, heads=2, ff=32, dropout=0.1, max_tokens=20)
TINY = UNetConfig(base_dim=16, dim_mults=(1, 2, 2, 2), groups=4, time_dim=32, attn_heads=2, dropout=0.1)


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """These models are tiny: extra threads only add synchronisation (and stall on a busy machine)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def make(cfg: UNetConfig = TINY, seed: int = 0, randomize: bool = True) -> CondUNet1D:
    """A tiny model; ``randomize`` re-draws every all-zero parameter (zero-initialised output conv, AdaGN maps,
    attention values, biases) so that every path actually contributes to the output."""
    torch.manual_seed(seed)
    model = CondUNet1D(cfg, D, TEXT)
    if randomize:
        with torch.no_grad():
            for p in model.parameters():
                if not p.any():
                    p.normal_(0.0, 0.3)
    return model


def inputs(B: int, T: int, L: int = 7, seed: int = 1):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(B, T, D, generator=g)
    t = torch.randint(0, 1000, (B,), generator=g)
    tokens = torch.randn(B, L, TEXT.in_dim, generator=g)
    text_mask = torch.ones(B, L, dtype=torch.bool)
    text_mask[0, L - 2:] = False
    return x, t, tokens, text_mask


@pytest.mark.parametrize("T", [1, 16, 37, 196])
def test_shape_and_zero_output_at_init(T):
    model = make(randomize=False).eval()
    x, t, tok, tm = inputs(2, T)
    with torch.no_grad():
        out = model(x, t, tok, tm)
    assert out.shape == x.shape
    assert torch.equal(out, torch.zeros_like(out))
    # randomized: a real, finite, non-zero output of the same shape
    with torch.no_grad():
        out = make().eval()(x, t, tok, tm, torch.tensor([False, True]), torch.ones(2, T, dtype=torch.bool))
    assert out.shape == x.shape and torch.isfinite(out).all() and out.abs().sum() > 0


def _padded_outputs(model, lengths, T_short, T_long, seed=3):
    """Outputs for the same valid frames inside a short and a long tensor, padded frames full of garbage."""
    g = torch.Generator().manual_seed(seed)
    B = len(lengths)
    _, t, tok, tm = inputs(B, T_short)
    valid = torch.randn(B, max(lengths), D, generator=g)
    outs = []
    for T in (T_short, T_long):
        x = 50.0 * torch.randn(B, T, D, generator=g)  # garbage everywhere ...
        mask = torch.zeros(B, T, dtype=torch.bool)
        for b, n in enumerate(lengths):
            x[b, :n] = valid[b, :n]  # ... except on the valid frames
            mask[b, :n] = True
        with torch.no_grad():
            outs.append(model(x, t, tok, tm, torch.tensor([False] * B), mask))
    return outs, valid, t, tok, tm


@pytest.mark.parametrize("attention", ["linear", "softmax"])
def test_padding_does_not_change_valid_frames_with_groupnorm_tweak(attention):
    model = make(replace(TINY, groupnorm_tweak=True, mask_padding=True, attention=attention)).eval()
    lengths = [37, 20]
    (short, long), valid, t, tok, tm = _padded_outputs(model, lengths, T_short=40, T_long=77)
    for b, n in enumerate(lengths):
        assert short[b, :n].abs().max() > 1e-2  # the comparison means something
        torch.testing.assert_close(short[b, :n], long[b, :n], atol=1e-5, rtol=1e-5)
        # ... and equals the sample run alone, with no padding of its own at all
        with torch.no_grad():
            alone = model(valid[b:b + 1, :n], t[b:b + 1], tok[b:b + 1], tm[b:b + 1], torch.tensor([False]))
        torch.testing.assert_close(short[b, :n], alone[0], atol=1e-5, rtol=1e-5)
    # padded frames come out as zeros
    assert torch.equal(short[1, 20:], torch.zeros_like(short[1, 20:]))


@pytest.mark.parametrize("flags", [dict(groupnorm_tweak=False, mask_padding=True),
                                   dict(groupnorm_tweak=True, mask_padding=False)])
def test_padding_leaks_without_the_tweak_or_the_mask(flags):
    model = make(replace(TINY, **flags)).eval()
    lengths = [37, 20]
    (short, long), *_ = _padded_outputs(model, lengths, T_short=40, T_long=77)
    for b, n in enumerate(lengths):
        assert (short[b, :n] - long[b, :n]).abs().max() > 1e-3


def test_frame_group_norm_is_per_frame():
    norm = FrameGroupNorm(2, 6)
    with torch.no_grad():
        norm.weight.normal_()
        norm.bias.normal_()
    x = torch.randn(3, 6, 10)
    y = norm(x)
    ref = torch.nn.functional.group_norm(x.transpose(1, 2).reshape(30, 6), 2, norm.weight, norm.bias)
    torch.testing.assert_close(y, ref.reshape(3, 10, 6).transpose(1, 2), atol=1e-5, rtol=1e-5)
    x2 = x.clone()
    x2[..., 5:] = 1000.0 * torch.randn(3, 6, 5)
    torch.testing.assert_close(norm(x2)[..., :5], y[..., :5])


@pytest.mark.parametrize("cross_attention,attention", [(True, "linear"), (True, "softmax"), (False, "linear")])
def test_text_padding_tokens_are_ignored(cross_attention, attention):
    # float64: a different token count changes float32 summation order (~1e-5 noise), not the result
    model = make(replace(TINY, cross_attention=cross_attention, attention=attention)).eval().double()
    x, t, tok, tm = inputs(2, 30, L=7)
    x, tok = x.double(), tok.double()
    g = torch.Generator().manual_seed(5)
    tok2 = torch.cat([tok, torch.randn(2, 6, TEXT.in_dim, generator=g, dtype=torch.float64) * 30], dim=1)
    tok2[0, 5:7] = 30 * torch.randn(2, TEXT.in_dim, generator=g, dtype=torch.float64)  # garbage on sample 0's own padding too
    tm2 = torch.cat([tm, torch.zeros(2, 6, dtype=torch.bool)], dim=1)
    drop = torch.tensor([False, False])
    with torch.no_grad():
        a = model(x, t, tok, tm, drop)
        b = model(x, t, tok2, tm2, drop)
    torch.testing.assert_close(a, b, atol=1e-10, rtol=1e-10)


@pytest.mark.parametrize("cross_attention,attention", [(True, "linear"), (True, "softmax"), (False, "linear")])
def test_drop_cond_makes_output_independent_of_text(cross_attention, attention):
    model = make(replace(TINY, cross_attention=cross_attention, attention=attention)).eval()
    x, t, tok, tm = inputs(2, 30, L=7)
    g = torch.Generator().manual_seed(9)
    other = torch.randn(2, 4, TEXT.in_dim, generator=g)
    other_mask = torch.tensor([[True, True, False, False], [True, True, True, True]])
    with torch.no_grad():
        dropped = [model(x, t, tk, m, torch.tensor([True, True])) for tk, m in ((tok, tm), (other, other_mask))]
        kept = [model(x, t, tk, m, torch.tensor([False, False])) for tk, m in ((tok, tm), (other, other_mask))]
    torch.testing.assert_close(dropped[0], dropped[1], atol=1e-6, rtol=1e-6)
    assert (kept[0] - kept[1]).abs().max() > 1e-3  # the text does matter when it is kept


@pytest.mark.parametrize("kind", ["linear", "softmax"])
def test_attention_ignores_padded_tokens_and_survives_empty_text(kind):
    torch.manual_seed(0)
    attn = CrossAttention(8, 6, heads=2, kind=kind)
    torch.nn.init.normal_(attn.value.weight)
    x, text = torch.randn(2, 5, 8), torch.randn(2, 4, 6)
    mask = torch.tensor([[True, True, False, False], [False, False, False, False]])
    y = attn(x, text, mask)
    assert torch.isfinite(y).all()
    torch.testing.assert_close(y[1], torch.zeros_like(y[1]))  # no valid token: no text contribution
    text2 = text.clone()
    text2[0, 2:] = 1e3 * torch.randn(2, 6)
    torch.testing.assert_close(attn(x, text2, mask), y)


@pytest.mark.parametrize("flags", [
    dict(),
    dict(cross_attention=False),
    dict(attention="softmax"),
    dict(adagn=False, groupnorm_tweak=False, mask_padding=False),
    dict(blocks_per_level=1, dim_mults=(1, 2), kernel=3),
])
def test_flags_build_run_and_train(flags):
    cfg = replace(TINY, **flags)
    model = make(cfg).train()
    x, t, tok, tm = inputs(2, 23)
    mask = torch.ones(2, 23, dtype=torch.bool)
    mask[1, 15:] = False
    out = model(x, t, tok, tm, torch.tensor([False, False]), mask)
    assert out.shape == x.shape
    out.pow(2).mean().backward()
    dead = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert not dead, f"no gradient reaches {dead}"
    if not cfg.cross_attention:
        assert not any(".attn." in n for n, _ in model.named_parameters())


def test_config_json_roundtrip_and_validation():
    d = json.loads(json.dumps(asdict(TINY)))
    assert d["dim_mults"] == [1, 2, 2, 2]
    assert UNetConfig(**d) == TINY
    with pytest.raises(ValueError):
        UNetConfig(attention="flash")
    with pytest.raises(ValueError):
        UNetConfig(base_dim=20, groups=8)


def test_build_denoiser(monkeypatch):
    # build_denoiser imports every architecture module; stand in for ones not written yet.
    for name in ("dit", "retnet"):
        full = f"stablemofusion.models.{name}"
        if importlib.util.find_spec(full) is None:
            monkeypatch.setitem(sys.modules, full, types.ModuleType(full))
    mc = ModelConfig(arch="unet", motion_dim=D, text=TEXT, options=asdict(TINY))
    mc = ModelConfig.from_dict(json.loads(json.dumps(mc.to_dict())))
    model = build_denoiser(mc)
    assert isinstance(model, CondUNet1D) and model.config == TINY
    x, t, tok, tm = inputs(1, 9)
    with torch.no_grad():
        assert model.eval()(x, t, tok, tm).shape == x.shape


def test_paper_and_small_parameter_counts():
    with torch.device("meta"):
        paper = build_denoiser(get_preset("paper"))
        small = build_denoiser(get_preset("small"))
    assert 290e6 < paper.num_parameters() < 300e6  # StableMoFusion reports ~294M
    assert small.num_parameters() < 10e6
    x, t, tok, tm = inputs(2, 196)
    model = CondUNet1D(UNetConfig(**get_preset("small").options), D, TEXT).eval()
    with torch.no_grad():
        assert model(x, t, tok, tm, torch.tensor([False, True])).shape == x.shape
