"""Attention pieces the transformer denoisers share (DiT, RetNet): masked multi-head attention, the
feed-forward block, adaLN modulation and zero-initialised projections."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import SMFError


def masked_attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, mask: torch.Tensor,
                     dropout: float = 0.0) -> torch.Tensor:
    """q (B, H, N, d), k/v (B, H, M, d), mask (B, M) bool True on keys to use -> (B, H, N, d).

    Rows of a sample with no usable key (e.g. dropped text under cross-attention) return zeros.
    """
    has = mask.any(-1)
    m = (mask | ~has[:, None])[:, None, None, :]
    out = F.scaled_dot_product_attention(q, k, v, attn_mask=m, dropout_p=dropout)
    return out * has[:, None, None, None].to(out.dtype)


class Attention(nn.Module):
    """Multi-head attention: x (B, N, dim) attends to ctx (B, M, dim) (None: self) with key mask (B, M)."""

    def __init__(self, dim: int, heads: int, dropout: float = 0.0):
        super().__init__()
        if dim % heads:
            raise SMFError(f"dim {dim} is not divisible by heads {heads}")
        self.heads, self.dropout = heads, dropout
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(dim, 2 * dim)
        self.out = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor, mask: torch.Tensor, ctx: torch.Tensor | None = None) -> torch.Tensor:
        ctx = x if ctx is None else ctx
        B, N, C = x.shape
        q = self.q(x).view(B, N, self.heads, -1).transpose(1, 2)
        k, v = self.kv(ctx).view(B, ctx.shape[1], 2, self.heads, -1).permute(2, 0, 3, 1, 4)
        o = masked_attention(q, k, v, mask, self.dropout if self.training else 0.0)
        return self.out(o.transpose(1, 2).reshape(B, N, C))


def feed_forward(dim: int, mult: int, dropout: float) -> nn.Sequential:
    return nn.Sequential(nn.Linear(dim, mult * dim), nn.GELU(approximate="tanh"), nn.Dropout(dropout),
                         nn.Linear(mult * dim, dim))


def modulate(x: torch.Tensor, shift: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    return x * (1 + scale) + shift


def zero_linear(i: int, o: int) -> nn.Linear:
    lin = nn.Linear(i, o)
    nn.init.zeros_(lin.weight)
    nn.init.zeros_(lin.bias)
    return lin
