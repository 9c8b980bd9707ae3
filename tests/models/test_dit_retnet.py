"""DiT and RetNet denoisers: shapes, zero init, padding/text-mask invariance, CFG dropping, gradients."""

from __future__ import annotations

import importlib.util
import sys
import types
from dataclasses import asdict

import pytest
import torch

from stablemofusion.core.errors import SMFError
from stablemofusion.models.base import DENOISERS, ModelConfig, TextConfig
from stablemofusion.models.registry import build_denoiser
from stablemofusion.models.dit import DiT, DiTConfig
from stablemofusion.models.retnet import RetNet, RetNetConfig

D, TEXT = 7, TextConfig(in_dim=16, latent=24, layers=1, heads=2, ff=32, dropout=0.1, max_tokens=16)
VARIANTS = [(DiT, DiTConfig, False), (DiT, DiTConfig, True), (RetNet, RetNetConfig, False),
            (RetNet, RetNetConfig, True)]
IDS = ["dit", "dit-xattn", "retnet", "retnet-xattn"]


def make(cls, cfg_cls, xattn: bool, randomise: bool = True) -> torch.nn.Module:
    torch.manual_seed(0)
    model = cls(cfg_cls(dim=32, layers=2, heads=4, ff_mult=2, time_dim=40, cross_attention=xattn), D, TEXT)
    if randomise:  # undo the zero init (output layer, adaLN-Zero) so every path is live
        with torch.no_grad():
            for p in model.parameters():
                if (p == 0).all():
                    p.normal_(0.0, 0.3)
    return model.eval()


def inputs(B: int = 2, T: int = 10, L: int = 8):
    g = torch.Generator().manual_seed(1)
    x = torch.randn(B, T, D, generator=g)
    t = torch.tensor([3, 870])[:B]
    tok = torch.randn(B, L, TEXT.in_dim, generator=g)
    tmask = torch.arange(L)[None] < torch.tensor([L, 5])[:B, None]
    mmask = torch.arange(T)[None] < torch.tensor([T, 6])[:B, None]
    return x, t, tok, tmask, mmask


@pytest.mark.parametrize("cls,cfg_cls,xattn", VARIANTS, ids=IDS)
def test_shape_and_zero_init(cls, cfg_cls, xattn):
    model = make(cls, cfg_cls, xattn, randomise=False)
    x, t, tok, tmask, mmask = inputs()
    out = model(x, t, tok, tmask, torch.tensor([False, True]), mmask)
    assert out.shape == x.shape
    assert torch.equal(out, torch.zeros_like(out))
    assert model(x, t, tok, tmask, None, None).abs().max() == 0


@pytest.mark.parametrize("cls,cfg_cls,xattn", VARIANTS, ids=IDS)
def test_padding_frames_do_not_leak(cls, cfg_cls, xattn):
    model = make(cls, cfg_cls, xattn)
    x, t, tok, tmask, mmask = inputs()
    with torch.no_grad():
        ref = model(x, t, tok, tmask, None, mmask)
        x2 = torch.cat([x, 50 * torch.randn(2, 5, D)], 1)
        x2[1, 6:] = 50 * torch.randn(9, D)  # garbage in sample 1's existing padding too
        m2 = torch.cat([mmask, torch.zeros(2, 5, dtype=torch.bool)], 1)
        out = model(x2, t, tok, tmask, None, m2)
    assert out.abs().max() > 1e-3
    torch.testing.assert_close(out[0, :10], ref[0], atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(out[1, :6], ref[1, :6], atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("cls,cfg_cls,xattn", VARIANTS, ids=IDS)
def test_text_padding_does_not_leak(cls, cfg_cls, xattn):
    model = make(cls, cfg_cls, xattn)
    x, t, tok, tmask, mmask = inputs()
    with torch.no_grad():
        ref = model(x, t, tok, tmask, None, mmask)
        tok2 = torch.cat([tok, 50 * torch.randn(2, 4, TEXT.in_dim)], 1)
        tok2[1, 5:] = 50 * torch.randn(7, TEXT.in_dim)
        tm2 = torch.cat([tmask, torch.zeros(2, 4, dtype=torch.bool)], 1)
        out = model(x, t, tok2, tm2, None, mmask)
    torch.testing.assert_close(out[:, :10][mmask], ref[mmask], atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("cls,cfg_cls,xattn", VARIANTS, ids=IDS)
def test_drop_cond_ignores_text(cls, cfg_cls, xattn):
    model = make(cls, cfg_cls, xattn)
    x, t, tok, tmask, mmask = inputs()
    other_tok = torch.randn(2, 12, TEXT.in_dim)
    other_mask = torch.arange(12)[None] < torch.tensor([[3], [12]])
    drop = torch.tensor([True, True])
    with torch.no_grad():
        a = model(x, t, tok, tmask, drop, mmask)
        b = model(x, t, other_tok, other_mask, drop, mmask)
        c = model(x, t, other_tok, other_mask, ~drop, mmask)
        d = model(x, t, other_tok, other_mask, torch.tensor([True, False]), mmask)
    torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-4)
    assert (a - c).abs().max() > 1e-3  # the text does matter when kept
    torch.testing.assert_close(d[0], a[0], atol=1e-5, rtol=1e-4)  # per-sample dropping


@pytest.mark.parametrize("cls,cfg_cls,xattn", VARIANTS, ids=IDS)
def test_gradients_reach_all_parameters(cls, cfg_cls, xattn):
    model = make(cls, cfg_cls, xattn).train()
    x, t, tok, tmask, mmask = inputs()
    model(x, t, tok, tmask, torch.tensor([False, False]), mmask).pow(2).mean().backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or p.grad.abs().max() == 0]
    assert not missing


def test_decay_and_registry():
    model = make(RetNet, RetNetConfig, False)
    assert torch.allclose(model.log_gamma.exp(), 1 - 2.0 ** (-5 - torch.arange(4.0)))
    assert DENOISERS["dit"] is DiT and DENOISERS["retnet"] is RetNet


@pytest.mark.parametrize("arch,cfg", [("dit", DiTConfig(dim=32, layers=1, time_dim=40, cross_attention=True)),
                                      ("retnet", RetNetConfig(dim=32, layers=1, time_dim=40))])
def test_build_denoiser(arch, cfg, monkeypatch):
    if importlib.util.find_spec("stablemofusion.models.unet1d") is None:  # build_denoiser imports it
        monkeypatch.setitem(sys.modules, "stablemofusion.models.unet1d", types.ModuleType("unet1d"))
    model = build_denoiser(ModelConfig(arch=arch, motion_dim=D, text=TEXT, options=asdict(cfg)))
    assert type(model) is DENOISERS[arch] and model.config == cfg
    x, t, tok, tmask, mmask = inputs()
    assert model(x, t, tok, tmask, None, mmask).shape == x.shape


def test_dit_rejects_too_many_frames():
    model = DiT(DiTConfig(dim=32, layers=1, time_dim=40, max_frames=8), D, TEXT)
    x, t, tok, tmask, mmask = inputs()
    with pytest.raises(SMFError, match="more than the 8"):
        model(x, t, tok, tmask, None, mmask)
