import pytest
import torch

from stablemofusion.models.dropout import KEEP_BITS, Dropout, dropout
from stablemofusion.models.registry import build_denoiser
from stablemofusion.models.presets import get_preset


def test_drops_each_element_with_probability_p_and_keeps_the_mean():
    torch.manual_seed(0)
    y = dropout(torch.ones(400_000), 0.1)
    dropped = (y == 0).float()
    # every one of the four 16-bit lanes of a 64-bit draw drops at p (a lane with a fixed bit would not)
    for lane in range(4):
        assert dropped[lane::4].mean().item() == pytest.approx(0.1, abs=0.004)
    # two lanes of one draw are independent: both dropped about p * p of the time
    assert (dropped[0::4] * dropped[1::4]).mean().item() == pytest.approx(0.01, abs=0.002)
    cut = round(0.1 * 2**KEEP_BITS)
    values = torch.unique(y).tolist()
    assert values[0] == 0.0 and values[1:] == [pytest.approx(2**KEEP_BITS / (2**KEEP_BITS - cut))]
    assert y.mean().item() == pytest.approx(1.0, abs=0.01)


def test_identity_in_evaluation_and_at_zero_and_gradient_is_the_mask():
    x = torch.randn(3, 5, 7, requires_grad=True)
    assert dropout(x, 0.3, training=False) is x
    assert dropout(x, 0.0) is x
    torch.manual_seed(1)
    y = dropout(x, 0.3)
    y.sum().backward()
    keep = y.detach() != 0
    scale = (y.detach()[keep] / x.detach()[keep]).unique()
    assert torch.allclose(scale, scale[0]) and x.grad[keep].allclose(scale[0].expand(int(keep.sum())))
    assert (x.grad[~keep] == 0).all()
    assert dropout(torch.ones(10), 1.0).eq(0).all()


def test_seeded_like_torch_and_keeps_dtype_and_shape():
    x = torch.randn(2, 9, 13, dtype=torch.bfloat16)
    torch.manual_seed(7)
    a = dropout(x, 0.2)
    torch.manual_seed(7)
    b = dropout(x, 0.2)
    assert a.dtype == torch.bfloat16 and a.shape == x.shape and torch.equal(a, b)


def test_module_and_every_denoiser_use_it():
    m = Dropout(0.25)
    assert "p=0.25" in repr(m)
    with pytest.raises(ValueError, match="probability"):
        Dropout(1.5)
    for preset in ("small-sentence", "dit-xattn", "retnet-xattn"):
        model = build_denoiser(get_preset(preset, motion_dim=263, text_dim=384))
        assert not any(isinstance(x, torch.nn.Dropout) for x in model.modules()), preset
        assert any(isinstance(x, Dropout) for x in model.modules()), preset
