"""RetNet denoiser: multi-scale retention blocks (Sun et al. 2023, "Retentive Network") over frames.

An architecture-ablation alternative to the Conv1D UNet (StableMoFusion compared against it; its code
was never released). Retention runs in the parallel form ``(Q K^T * D) V`` with per-head decay
``gamma_h = 1 - 2^(-5-h)``. A denoiser sees the whole sequence at once, so the decay mask is
BIDIRECTIONAL, ``D[n, m] = gamma^|n-m|``, instead of RetNet's causal ``gamma^(n-m)`` for n >= m.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .dropout import Dropout
from ..core.errors import SMFError
from .base import Denoiser, TextCondition, TextConfig, register
from .attention import Attention
from .embeddings import TimestepEmbedding


@dataclass
class RetNetConfig:
    dim: int = 256  # token width (also the value width)
    layers: int = 4
    heads: int = 4  # retention scales: gamma_h = 1 - 2^(-5-h)
    ff_mult: int = 2  # FFN hidden width = ff_mult * dim
    dropout: float = 0.1  # on sublayer outputs and the FFN hidden layer
    cross_attention: bool = False  # False: text tokens concatenated with the motion sequence
    time_dim: int = 512  # timestep-embedding width before its projection to a token


def rotate(x: torch.Tensor, pos: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """Rotary position: x (B, H, N, d), pos (N,), theta (d/2,) -> x with pairs rotated by pos * theta."""
    ang = pos[:, None] * theta[None]
    cos, sin = ang.cos(), ang.sin()
    x1, x2 = x[..., 0::2], x[..., 1::2]
    return torch.stack([x1 * cos - x2 * sin, x1 * sin + x2 * cos], dim=-1).flatten(-2)


class MultiScaleRetention(nn.Module):
    """Bidirectional multi-scale retention: ``W_o(GroupNorm(Retention(X)) * swish(X W_g))``.

    Q/K carry rotary relative positions (the xPos rotation; its magnitude term is the explicit decay).
    """

    def __init__(self, dim: int, heads: int):
        super().__init__()
        if dim % heads or (dim // heads) % 2:
            raise SMFError(f"dim {dim} must split into {heads} heads of even width")
        self.heads, self.hd = heads, dim // heads
        self.qkv = nn.Linear(dim, 3 * dim, bias=False)
        self.gate = nn.Linear(dim, dim, bias=False)
        self.out = nn.Linear(dim, dim, bias=False)
        self.gn = nn.GroupNorm(heads, dim)
        self.register_buffer("theta", 10000.0 ** (-torch.arange(0, self.hd, 2, dtype=torch.float32) / self.hd),
                             persistent=False)

    def forward(self, x: torch.Tensor, pos: torch.Tensor, decay: torch.Tensor) -> torch.Tensor:
        """x (B, N, dim), pos (N,) rotary positions, decay (B, H, N, N) normalised masked D -> (B, N, dim)."""
        B, N, C = x.shape
        q, k, v = self.qkv(x).view(B, N, 3, self.heads, self.hd).permute(2, 0, 3, 1, 4)
        q, k = rotate(q, pos, self.theta), rotate(k, pos, self.theta) * self.hd ** -0.5
        r = (q @ k.transpose(-1, -2)) * decay
        r = r / r.sum(-1, keepdim=True).abs().clamp(min=1.0)
        o = (r @ v).transpose(1, 2).reshape(B * N, C)
        o = self.gn(o).view(B, N, C)
        return self.out(o * F.silu(self.gate(x)))


class RetNetBlock(nn.Module):
    """Pre-norm block: retention, optional cross-attention to text, FFN; all residual."""

    def __init__(self, cfg: RetNetConfig):
        super().__init__()
        d = cfg.dim
        self.norm1 = nn.LayerNorm(d)
        self.msr = MultiScaleRetention(d, cfg.heads)
        self.xnorm = nn.LayerNorm(d) if cfg.cross_attention else None
        self.xattn = Attention(d, cfg.heads, cfg.dropout) if cfg.cross_attention else None
        self.norm2 = nn.LayerNorm(d)
        self.ffn = nn.Sequential(nn.Linear(d, cfg.ff_mult * d), nn.GELU(), Dropout(cfg.dropout),
                                 nn.Linear(cfg.ff_mult * d, d))
        self.drop = Dropout(cfg.dropout)

    def forward(self, x: torch.Tensor, pos: torch.Tensor, decay: torch.Tensor, text: torch.Tensor,
                text_mask: torch.Tensor) -> torch.Tensor:
        """x (B, N, dim), text (B, L, dim), text_mask (B, L) -> (B, N, dim)."""
        x = x + self.drop(self.msr(self.norm1(x), pos, decay))
        if self.xattn is not None:
            x = x + self.drop(self.xattn(self.xnorm(x), text_mask, text))
        return x + self.drop(self.ffn(self.norm2(x)))


@register("retnet")
class RetNet(Denoiser):
    """Retentive-network denoiser; (B, T, motion_dim) -> x0 (B, T, motion_dim).

    Sequence = [motion frames (positions 0..T-1), timestep token, text tokens (baseline only)].
    Conditioning tokens are global: rotary position 0 and no decay to or from them (decay 1), so
    every frame sees them at full strength and their count (text padding) moves no frame.
    Decay between frames is ``gamma_h^|n-m|``. Padded frames and padded/dropped text tokens are
    zeroed out of D as keys, so they never influence valid frames. With ``cross_attention`` the text
    enters through a cross-attention sublayer between retention and FFN instead. Output: LayerNorm +
    zero-initialised linear.
    """

    config_class = RetNetConfig

    def __init__(self, config: RetNetConfig, motion_dim: int, text: TextConfig):
        super().__init__(text)
        self.config = config
        d = config.dim
        self.in_proj = nn.Linear(motion_dim, d)
        self.time = TimestepEmbedding(d, config.time_dim)
        self.time_proj = nn.Linear(config.time_dim, d)
        self.init_sentence_condition(config.time_dim)
        self.text_proj = nn.Linear(text.latent, d)
        self.blocks = nn.ModuleList(RetNetBlock(config) for _ in range(config.layers))
        self.norm = nn.LayerNorm(d)
        self.out = nn.Linear(d, motion_dim)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        h = torch.arange(config.heads, dtype=torch.float32)
        self.register_buffer("log_gamma", torch.log1p(-(2.0 ** (-5.0 - h))), persistent=False)

    def decay_matrix(self, is_motion: torch.Tensor, pos: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """is_motion/pos (N,), key mask (B, N) -> D (B, H, N, N), rows normalised by sqrt of their sum."""
        both = is_motion[:, None] & is_motion[None, :]
        dist = (pos[:, None] - pos[None, :]).abs() * both
        d = torch.exp(self.log_gamma[:, None, None] * dist)[None] * mask[:, None, None, :].to(dist.dtype)
        return d / d.sum(-1, keepdim=True).clamp(min=1e-6).sqrt()

    def denoise(self, x_t: torch.Tensor, t: torch.Tensor, cond: TextCondition,
                motion_mask: torch.Tensor | None = None) -> torch.Tensor:
        B, T, _ = x_t.shape
        dev = x_t.device
        if motion_mask is None:
            motion_mask = torch.ones(B, T, dtype=torch.bool, device=dev)
        txt = self.text_proj(cond.features)
        tmask = cond.mask if cond.keep is None else cond.mask & cond.keep[:, None]
        c = self.time(t)
        if cond.sentence is not None:
            c = c + cond.sentence.to(c.dtype)
        parts = [self.in_proj(x_t), self.time_proj(c)[:, None]]
        masks = [motion_mask, torch.ones(B, 1, dtype=torch.bool, device=dev)]
        if not self.config.cross_attention:
            parts.append(txt)
            masks.append(tmask)
        seq, mask = torch.cat(parts, 1), torch.cat(masks, 1)
        N = seq.shape[1]
        pos = torch.cat([torch.arange(T, device=dev, dtype=torch.float32), torch.zeros(N - T, device=dev)])
        decay = self.decay_matrix(torch.arange(N, device=dev) < T, pos, mask).to(seq.dtype)
        for blk in self.blocks:
            seq = blk(seq, pos, decay, txt, tmask)
        return self.out(self.norm(seq[:, :T]))
