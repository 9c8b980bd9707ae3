"""Attention of every denoiser: cross-attention from motion frames to text tokens, in the linear
(StableMoFusion) and softmax forms (the UNet); masked multi-head self-attention with the feed-forward block,
adaLN modulation and zero-initialised projections that the transformers (DiT, RetNet) share.

Both work per motion frame: the queries of one frame never see another frame, and the motion side is
normalised with a per-frame LayerNorm, so padded motion frames cannot influence valid ones. Padded text
tokens (``text_mask`` False) get no weight at all, whatever their values.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .dropout import Dropout
from ..core.errors import SMFError


def _masked_softmax(logits: torch.Tensor, mask: torch.Tensor, dim: int) -> torch.Tensor:
    """Softmax along ``dim`` with the ``mask``-False entries weighted exactly 0 (all masked -> all 0)."""
    logits = logits.masked_fill(~mask, torch.finfo(logits.dtype).min)
    return torch.softmax(logits, dim=dim) * mask.to(logits.dtype)


class CrossAttention(nn.Module):
    """Multi-head cross-attention ``(B, T, dim) x (B, L, text_dim) -> (B, T, dim)`` (the residual branch).

    ``kind="linear"``: queries softmax-normalised over the features of each head, keys softmax-normalised
    over the (valid) tokens, out = Q (K^T V): cost linear in T and L. ``kind="softmax"``: the usual
    softmax(Q K^T / sqrt(d)) V over the valid tokens. The value projection starts at zero, so a freshly
    built layer outputs zeros (its residual leaves the input unchanged).
    """

    def __init__(self, dim: int, text_dim: int, heads: int = 8, dropout: float = 0.0, kind: str = "linear"):
        super().__init__()
        if kind not in ("linear", "softmax"):
            raise ValueError(f"attention must be 'linear' or 'softmax', not {kind!r}")
        if dim % heads:
            raise ValueError(f"{dim} channels do not split into {heads} heads")
        self.heads = heads
        self.kind = kind
        self.norm = nn.LayerNorm(dim)
        self.text_norm = nn.LayerNorm(text_dim)
        self.query = nn.Linear(dim, dim)
        self.key = nn.Linear(text_dim, dim)
        self.value = nn.Linear(text_dim, dim)
        self.dropout = Dropout(dropout)
        # The branch is linear in the values, so zero values make a fresh layer output exactly zero; like the
        # StableMoFusion layer there is no separate output projection (it would add dim^2 per layer).
        nn.init.zeros_(self.value.weight)
        nn.init.zeros_(self.value.bias)

    def forward(self, x: torch.Tensor, text: torch.Tensor, text_mask: torch.Tensor) -> torch.Tensor:
        """x (B, T, dim), text (B, L, text_dim), text_mask (B, L) bool True on real tokens -> (B, T, dim)."""
        B, T, D = x.shape
        L, H = text.shape[1], self.heads
        q = self.query(self.norm(x)).view(B, T, H, D // H)
        t = self.text_norm(text)
        k = self.key(t).view(B, L, H, D // H)
        v = self.value(t).view(B, L, H, D // H)
        if self.kind == "linear":
            q = torch.softmax(q, dim=-1)
            k = _masked_softmax(k, text_mask[:, :, None, None], dim=1)
            context = self.dropout(torch.einsum("blhd,blhe->bhde", k, v))  # (B, H, d, d)
            y = torch.einsum("bthd,bhde->bthe", q, context)
        else:
            logits = torch.einsum("bthd,blhd->bhtl", q, k) * (D // H) ** -0.5
            w = self.dropout(_masked_softmax(logits, text_mask[:, None, None, :], dim=-1))
            y = torch.einsum("bhtl,blhd->bthd", w, v)
        return y.reshape(B, T, D)


class ResidualCrossAttention(nn.Module):
    """``x + attn(x)`` on channel-first activations (B, C, T); ``keep`` (B,) bool gates the text branch."""

    def __init__(self, dim: int, text_dim: int, heads: int = 8, dropout: float = 0.0, kind: str = "linear"):
        super().__init__()
        self.attn = CrossAttention(dim, text_dim, heads, dropout, kind)

    def forward(self, x: torch.Tensor, text: torch.Tensor, text_mask: torch.Tensor,
                keep: torch.Tensor | None = None) -> torch.Tensor:
        y = self.attn(x.transpose(1, 2), text, text_mask).transpose(1, 2)
        if keep is not None:
            y = y * keep.to(y.dtype)[:, None, None]
        return x + y


__all__ = ["CrossAttention", "ResidualCrossAttention"]


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
    return nn.Sequential(nn.Linear(dim, mult * dim), nn.GELU(approximate="tanh"), Dropout(dropout),
                         nn.Linear(mult * dim, dim))


def modulate(x: torch.Tensor, shift: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    return x * (1 + scale) + shift


def zero_linear(i: int, o: int) -> nn.Linear:
    lin = nn.Linear(i, o)
    nn.init.zeros_(lin.weight)
    nn.init.zeros_(lin.bias)
    return lin
