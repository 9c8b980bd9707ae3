"""Timestep embeddings shared by every denoiser."""

from __future__ import annotations

import math

import torch
from torch import nn


def sinusoidal_embedding(t: torch.Tensor, dim: int, max_period: float = 10000.0) -> torch.Tensor:
    """Diffusion timesteps (B,) (int or float) -> (B, dim) sin/cos features at geometric frequencies."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, dtype=torch.float32, device=t.device) / half)
    args = t.float()[:, None] * freqs[None]
    emb = torch.cat([torch.cos(args), torch.sin(args)], dim=-1)
    return nn.functional.pad(emb, (0, dim % 2))


class TimestepEmbedding(nn.Module):
    """Sinusoidal features (``dim``) followed by two linear layers with Mish: (B,) -> (B, out_dim)."""

    def __init__(self, dim: int, out_dim: int = 512):
        super().__init__()
        self.dim = dim
        self.mlp = nn.Sequential(nn.Linear(dim, out_dim), nn.Mish(), nn.Linear(out_dim, out_dim))

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        return self.mlp(sinusoidal_embedding(t, self.dim))


GUIDANCE_FEATURES = 64  # sinusoidal features of the guidance scale
GUIDANCE_FACTOR = 100.0  # (w - 1) * this is embedded: w 1..5 spans the features' periods


class GuidanceEmbedding(nn.Module):
    """A distilled student's guidance-scale input: sinusoidal features of ``(w - 1) * GUIDANCE_FACTOR``, two
    linear layers with Mish, the last zero-initialised, so a fresh embedding adds nothing (the student starts
    as its teacher's conditional branch). (B,) -> (B, out_dim), added to the timestep embedding."""

    def __init__(self, out_dim: int):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(GUIDANCE_FEATURES, out_dim), nn.Mish(), nn.Linear(out_dim, out_dim))
        nn.init.zeros_(self.mlp[2].weight)
        nn.init.zeros_(self.mlp[2].bias)

    def forward(self, w: torch.Tensor) -> torch.Tensor:
        feats = sinusoidal_embedding((w.float() - 1.0) * GUIDANCE_FACTOR, GUIDANCE_FEATURES)
        return self.mlp(feats.to(self.mlp[0].weight.dtype))
