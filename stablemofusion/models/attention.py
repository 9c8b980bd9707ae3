"""Cross-attention from motion frames to text tokens, in the linear (StableMoFusion) and softmax forms.

Both work per motion frame: the queries of one frame never see another frame, and the motion side is
normalised with a per-frame LayerNorm, so padded motion frames cannot influence valid ones. Padded text
tokens (``text_mask`` False) get no weight at all, whatever their values.
"""

from __future__ import annotations

import torch
from torch import nn


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
        self.dropout = nn.Dropout(dropout)
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
