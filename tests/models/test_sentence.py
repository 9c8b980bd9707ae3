"""The sentence-embedding global condition: pooling, zero start, dropped with the text for CFG."""

import dataclasses

import torch

from stablemofusion.models.base import ModelConfig
from stablemofusion.models.registry import build_denoiser
from stablemofusion.models.presets import get_preset
from stablemofusion.text.frozen import sentence_embedding


def test_sentence_embedding_is_the_normalised_mean_of_valid_tokens():
    tokens = torch.tensor([[[1.0, 0.0], [3.0, 4.0], [100.0, 100.0]]])
    mask = torch.tensor([[True, True, False]])
    expect = torch.tensor([[2.0, 2.0]]) / (8 ** 0.5)
    assert torch.allclose(sentence_embedding(tokens, mask), expect)
    assert torch.equal(sentence_embedding(tokens, mask, torch.tensor([True])), torch.zeros(1, 2))


def _pair(arch_preset: str):
    plain = get_preset(arch_preset)
    with_sentence = ModelConfig(plain.arch, plain.motion_dim, dataclasses.replace(plain.text, sentence=True),
                                dict(plain.options))
    torch.manual_seed(0)
    a = build_denoiser(plain).eval()
    with torch.no_grad():  # no zero-initialised layer left, so outputs depend on everything
        for p in a.parameters():
            if p.abs().sum() == 0:
                p.normal_(0, 0.02)
    b = build_denoiser(with_sentence).eval()
    missing, unexpected = b.load_state_dict(a.state_dict(), strict=False)
    assert set(missing) == {"sentence_proj.weight", "sentence_proj.bias"} and not unexpected
    return a, b


def test_zero_initialised_so_fine_tuning_starts_from_the_old_model():
    for preset in ("tiny", "dit", "retnet"):
        a, b = _pair(preset)
        x, t = torch.randn(2, 24, 263), torch.tensor([3, 700])
        tok, mask = torch.randn(2, 5, 384), torch.ones(2, 5, dtype=torch.bool)
        with torch.no_grad():
            out = a(x, t, tok, mask)
            assert out.abs().max() > 0
            assert torch.allclose(out, b(x, t, tok, mask), atol=1e-6), preset


def test_it_conditions_and_is_dropped_with_the_text():
    _, b = _pair("tiny")
    with torch.no_grad():
        b.sentence_proj.weight.normal_(0, 1.0)
    x, t = torch.randn(2, 24, 263), torch.tensor([3, 3])
    mask = torch.ones(2, 5, dtype=torch.bool)
    tok1, tok2 = torch.randn(2, 5, 384), torch.randn(2, 5, 384)
    drop = torch.tensor([True, True])
    with torch.no_grad():
        assert not torch.allclose(b(x, t, tok1, mask), b(x, t, tok2, mask))
        # dropped: neither the tokens nor the sentence embedding reach the output
        assert torch.allclose(b(x, t, tok1, mask, drop), b(x, t, tok2, mask, drop))
