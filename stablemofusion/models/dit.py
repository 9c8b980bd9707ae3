"""DiT denoiser (Peebles & Xie 2023) adapted to motion: adaLN-Zero transformer blocks over frames.

An architecture-ablation alternative to the Conv1D UNet (StableMoFusion compared against it; its code
was never released). Text enters either as extra tokens in the self-attention sequence (baseline) or
through a cross-attention sublayer in every block (``cross_attention=True``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ..core.errors import SMFError
from .attention import Attention, feed_forward, modulate, zero_linear
from .base import Denoiser, TextCondition, TextConfig, register
from .embeddings import TimestepEmbedding, sinusoidal_embedding


@dataclass
class DiTConfig:
    dim: int = 256  # token width
    layers: int = 4  # transformer blocks (8 for the larger model)
    heads: int = 4
    ff_mult: int = 4  # MLP hidden width = ff_mult * dim
    dropout: float = 0.1  # on attention weights and the MLP hidden layer
    cross_attention: bool = False  # False: text tokens concatenated into self-attention
    time_dim: int = 512  # timestep-embedding width feeding the adaLN modulation
    max_frames: int = 256  # learned positions (initialised sinusoidal)


class DiTBlock(nn.Module):
    """adaLN-Zero block: gated self-attention, optional cross-attention to text, gated MLP."""

    def __init__(self, cfg: DiTConfig):
        super().__init__()
        d = cfg.dim
        self.norm1 = nn.LayerNorm(d, elementwise_affine=False, eps=1e-6)
        self.attn = Attention(d, cfg.heads, cfg.dropout)
        self.xnorm = nn.LayerNorm(d) if cfg.cross_attention else None
        self.xattn = Attention(d, cfg.heads, cfg.dropout) if cfg.cross_attention else None
        self.norm2 = nn.LayerNorm(d, elementwise_affine=False, eps=1e-6)
        self.mlp = feed_forward(d, cfg.ff_mult, cfg.dropout)
        self.ada = nn.Sequential(nn.SiLU(), zero_linear(cfg.time_dim, 6 * d))

    def forward(self, x: torch.Tensor, c: torch.Tensor, mask: torch.Tensor, text: torch.Tensor,
                text_mask: torch.Tensor) -> torch.Tensor:
        """x (B, N, dim), c (B, time_dim), mask (B, N), text (B, L, dim), text_mask (B, L) -> (B, N, dim)."""
        s1, sc1, g1, s2, sc2, g2 = self.ada(c)[:, None].chunk(6, dim=-1)
        x = x + g1 * self.attn(modulate(self.norm1(x), s1, sc1), mask)
        if self.xattn is not None:
            x = x + self.xattn(self.xnorm(x), text_mask, text)
        return x + g2 * self.mlp(modulate(self.norm2(x), s2, sc2))


@register("dit")
class DiT(Denoiser):
    """Diffusion transformer over motion frames; (B, T, motion_dim) -> x0 (B, T, motion_dim).

    Frames are projected to ``dim`` plus learned positions; the timestep conditions every block by
    adaLN-Zero. Padded frames (``motion_mask`` False) and padded or dropped text tokens are masked out
    as attention keys, so they never influence valid frames. Final adaLN + zero-initialised linear.
    """

    config_class = DiTConfig

    def __init__(self, config: DiTConfig, motion_dim: int, text: TextConfig):
        super().__init__(text)
        self.config = config
        d = config.dim
        self.in_proj = nn.Linear(motion_dim, d)
        self.pos = nn.Parameter(sinusoidal_embedding(torch.arange(config.max_frames), d)[None].clone())
        self.time = TimestepEmbedding(d, config.time_dim)
        self.init_sentence_condition(config.time_dim)
        self.text_proj = nn.Linear(text.latent, d)
        self.blocks = nn.ModuleList(DiTBlock(config) for _ in range(config.layers))
        self.final_norm = nn.LayerNorm(d, elementwise_affine=False, eps=1e-6)
        self.final_ada = nn.Sequential(nn.SiLU(), zero_linear(config.time_dim, 2 * d))
        self.out = zero_linear(d, motion_dim)

    def denoise(self, x_t: torch.Tensor, t: torch.Tensor, cond: TextCondition,
                motion_mask: torch.Tensor | None = None) -> torch.Tensor:
        B, T, _ = x_t.shape
        if T > self.config.max_frames:
            raise SMFError(f"motion has {T} frames, more than the {self.config.max_frames} this model takes")
        if motion_mask is None:
            motion_mask = torch.ones(B, T, dtype=torch.bool, device=x_t.device)
        txt = self.text_proj(cond.features)
        tmask = cond.mask if cond.keep is None else cond.mask & cond.keep[:, None]
        c = self.time(t)
        if cond.sentence is not None:
            c = c + cond.sentence.to(c.dtype)
        h = self.in_proj(x_t) + self.pos[:, :T]
        if self.config.cross_attention:
            seq, mask = h, motion_mask
        else:
            seq, mask = torch.cat([h, txt], 1), torch.cat([motion_mask, tmask], 1)
        for blk in self.blocks:
            seq = blk(seq, c, mask, txt, tmask)
        shift, scale = self.final_ada(c)[:, None].chunk(2, dim=-1)
        return self.out(modulate(self.final_norm(seq[:, :T]), shift, scale))
