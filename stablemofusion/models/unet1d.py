"""CondUNet1D: the StableMoFusion denoiser, a temporal 1D-convolution UNet with text cross-attention.

The layout follows the Diffuser-style temporal UNet that StableMoFusion builds on: an input projection,
``len(dim_mults)`` down levels (``blocks_per_level`` residual blocks, then a stride-2 convolution), a middle
of two residual blocks at the coarsest resolution, as many up levels (transposed-convolution upsampling,
concatenation with the matching skip, residual blocks) and a zero-initialised output convolution, so a
fresh model predicts zeros. Every residual block takes the diffusion step through AdaGN and is followed by
a residual cross-attention to the text tokens.

Each of the paper's adjustments is a flag of :class:`UNetConfig`, so its ablation is a config change:

* ``cross_attention=False`` is the baseline: the text enters only as a pooled vector added to the time
  embedding;
* ``attention`` picks the linear (default) or softmax cross-attention;
* ``groupnorm_tweak`` normalises every frame on its own (statistics over the channels of a group only), so
  the statistics never see padded frames; with it off the blocks use ``nn.GroupNorm`` over channels x time;
* ``mask_padding`` zeroes padded frames before every convolution and after every block, so no convolution
  can carry padding into valid frames either;
* ``adagn`` injects the time embedding as ``x * (1 + scale) + shift`` (otherwise it is added).

With ``groupnorm_tweak`` and ``mask_padding`` both on, a sample's output on its valid frames is independent of
how much padding follows it and of what the padded frames hold.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .dropout import Dropout
from .attention import ResidualCrossAttention
from .base import Denoiser, TextCondition, TextConfig, register
from .embeddings import TimestepEmbedding, sinusoidal_embedding


@dataclass
class UNetConfig:
    """Options of :class:`CondUNet1D` (all JSON-serialisable; ``dim_mults`` may come back as a list).

    Level ``i`` has ``int(base_dim * dim_mults[i])`` channels; the input projection maps the motion features
    to ``base_dim`` channels. Every level halves the frame rate, so the time axis is padded to a multiple of
    ``2 ** len(dim_mults)`` (at least 16) inside the model.
    """

    base_dim: int = 512
    dim_mults: tuple[float, ...] = (2, 2, 2, 2)
    blocks_per_level: int = 2
    kernel: int = 5
    groups: int = 8
    dropout: float = 0.1
    time_dim: int = 512
    attn_heads: int = 8
    cross_attention: bool = True
    attention: str = "linear"
    groupnorm_tweak: bool = True
    mask_padding: bool = True
    adagn: bool = True

    def __post_init__(self):
        self.dim_mults = tuple(self.dim_mults)
        if not self.dim_mults:
            raise ValueError("dim_mults must name at least one level")
        if self.attention not in ("linear", "softmax"):
            raise ValueError(f"attention must be 'linear' or 'softmax', not {self.attention!r}")
        if self.kernel % 2 != 1:
            raise ValueError(f"kernel must be odd to keep the frame count, not {self.kernel}")
        if self.blocks_per_level < 1:
            raise ValueError("blocks_per_level must be at least 1")
        for w in self.widths():
            if w % self.groups:
                raise ValueError(f"{w} channels do not split into {self.groups} groups")
            if self.cross_attention and w % self.attn_heads:
                raise ValueError(f"{w} channels do not split into {self.attn_heads} attention heads")

    def widths(self) -> list[int]:
        """Channels of every level, the input projection's first: [base_dim, base_dim*m_0, ...]."""
        return [self.base_dim] + [int(self.base_dim * m) for m in self.dim_mults]

    @property
    def pad_multiple(self) -> int:
        return max(16, 2 ** len(self.dim_mults))


class FrameGroupNorm(nn.Module):
    """GroupNorm whose statistics are taken per frame: (B, C, T) -> (B, G, C/G, T), normalised over C/G.

    Unlike ``nn.GroupNorm`` (statistics over the group's channels *and* all frames) no frame's statistics
    depend on any other frame, so padded frames cannot leak into valid ones. Affine weight/bias per channel.
    """

    def __init__(self, groups: int, channels: int, eps: float = 1e-5):
        super().__init__()
        if channels % groups:
            raise ValueError(f"{channels} channels do not split into {groups} groups")
        self.groups, self.eps = groups, eps
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, C, T = x.shape
        h = x.reshape(B, self.groups, C // self.groups, T)
        h = h - h.mean(dim=2, keepdim=True)  # (torch.var_mean over a middle dim is ~10x slower on CPU)
        h = (h * torch.rsqrt(h.square().mean(dim=2, keepdim=True) + self.eps)).reshape(B, C, T)
        return torch.addcmul(self.bias[:, None], h, self.weight[:, None])


def _norm(groups: int, channels: int, tweak: bool) -> nn.Module:
    return FrameGroupNorm(groups, channels) if tweak else nn.GroupNorm(groups, channels)


def _masked(x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    return x if mask is None else x * mask


class ResidualBlock(nn.Module):
    """Conv -> GroupNorm -> AdaGN(time) -> Mish -> dropout -> Conv -> GroupNorm -> Mish, plus a residual.

    AdaGN is ``x * (1 + scale) + shift`` with (scale, shift) a zero-initialised linear map of the time
    embedding (so it starts as the identity); with ``adagn=False`` the mapped embedding is added after the
    activation instead. The residual path is a 1x1 convolution when the channel count changes. ``mask``
    (B, 1, T) zeroes padded frames before the second convolution and on the output.
    """

    def __init__(self, cin: int, cout: int, time_dim: int, kernel: int, groups: int, dropout: float,
                 adagn: bool, tweak: bool):
        super().__init__()
        self.adagn = adagn
        self.conv1 = nn.Conv1d(cin, cout, kernel, padding=kernel // 2)
        self.norm1 = _norm(groups, cout, tweak)
        self.time = nn.Sequential(nn.Mish(), nn.Linear(time_dim, 2 * cout if adagn else cout))
        nn.init.zeros_(self.time[1].weight)
        nn.init.zeros_(self.time[1].bias)
        self.dropout = Dropout(dropout)
        self.conv2 = nn.Conv1d(cout, cout, kernel, padding=kernel // 2)
        self.norm2 = _norm(groups, cout, tweak)
        self.skip = nn.Conv1d(cin, cout, 1) if cin != cout else nn.Identity()

    def forward(self, x: torch.Tensor, temb: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        h = self.norm1(self.conv1(x))
        e = self.time(temb)[:, :, None]
        if self.adagn:
            scale, shift = e.chunk(2, dim=1)
            h = F.mish(h * (1 + scale) + shift)
        else:
            h = F.mish(h) + e
        h = _masked(self.dropout(h), mask)
        h = F.mish(self.norm2(self.conv2(h)))
        return _masked(h + self.skip(x), mask)


class CondBlock(nn.Module):
    """A residual block followed (when ``text_dim``) by a residual cross-attention to the text."""

    def __init__(self, cin: int, cout: int, cfg: UNetConfig, text_dim: int | None):
        super().__init__()
        self.res = ResidualBlock(cin, cout, cfg.time_dim, cfg.kernel, cfg.groups, cfg.dropout, cfg.adagn,
                                 cfg.groupnorm_tweak)
        self.attn = (ResidualCrossAttention(cout, text_dim, cfg.attn_heads, cfg.dropout, cfg.attention)
                     if text_dim else None)

    def forward(self, x, temb, mask, text, text_mask, keep):
        x = self.res(x, temb, mask)
        if self.attn is not None:
            x = _masked(self.attn(x, text, text_mask, keep), mask)
        return x


@register("unet")
class CondUNet1D(Denoiser):
    """The StableMoFusion denoiser; see the module docstring. ``forward`` as in :class:`Denoiser`."""

    config_class = UNetConfig

    def __init__(self, config: UNetConfig, motion_dim: int, text: TextConfig):
        super().__init__(text)
        cfg = self.config = config
        self.motion_dim = motion_dim
        text_dim = text.latent if cfg.cross_attention else None
        dims = cfg.widths()

        self.time_embed = TimestepEmbedding(cfg.time_dim, cfg.time_dim)
        self.init_sentence_condition(cfg.time_dim)
        # The baseline without cross-attention: a pooled text vector is added to the time embedding.
        self.text_pool = None if cfg.cross_attention else nn.Linear(text.latent, cfg.time_dim)
        self.input_proj = nn.Conv1d(motion_dim, dims[0], 1)

        def blocks(cin: int, cout: int) -> nn.ModuleList:
            return nn.ModuleList([CondBlock(cin if i == 0 else cout, cout, cfg, text_dim)
                                  for i in range(cfg.blocks_per_level)])

        self.downs = nn.ModuleList()
        for cin, cout in zip(dims[:-1], dims[1:]):
            self.downs.append(nn.ModuleDict({"blocks": blocks(cin, cout),
                                             "down": nn.Conv1d(cout, cout, 3, stride=2, padding=1)}))
        self.mid = nn.ModuleList([CondBlock(dims[-1], dims[-1], cfg, text_dim) for _ in range(2)])
        self.ups = nn.ModuleList()
        last = dims[-1]
        for cout in reversed(dims[1:]):
            self.ups.append(nn.ModuleDict({"up": nn.ConvTranspose1d(last, cout, 4, stride=2, padding=1),
                                           "blocks": blocks(2 * cout, cout)}))
            last = cout
        self.out = nn.Conv1d(last, motion_dim, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    @property
    def padding_invariant(self) -> bool:
        return self.config.mask_padding

    def denoise(self, x_t: torch.Tensor, t: torch.Tensor, cond: TextCondition,
                motion_mask: torch.Tensor | None = None) -> torch.Tensor:
        cfg = self.config
        B, T, _ = x_t.shape
        text, text_mask, keep = cond.features, cond.mask, cond.keep
        # (sinusoidal_embedding is always float32; cast so the model also runs in float64 / half precision)
        temb = self.time_embed.mlp(sinusoidal_embedding(t, self.time_embed.dim).to(x_t.dtype))
        if self.text_pool is not None:
            m = text_mask[..., None].to(text.dtype)
            pooled = (text * m).sum(1) / m.sum(1).clamp(min=1.0)
            temb = temb + self.text_pool(pooled)
        if cond.sentence is not None:
            temb = temb + cond.sentence.to(temb.dtype)

        pad = (-T) % cfg.pad_multiple
        x = F.pad(x_t.transpose(1, 2), (0, pad))
        mask = None
        if cfg.mask_padding:
            valid = (torch.ones(B, T, dtype=torch.bool, device=x.device) if motion_mask is None
                     else motion_mask.bool())
            mask = F.pad(valid, (0, pad), value=False)[:, None, :].to(x.dtype)  # (B, 1, T + pad)
        x = _masked(self.input_proj(_masked(x, mask)), mask)

        skips, masks = [], []
        for level in self.downs:
            for block in level["blocks"]:
                x = block(x, temb, mask, text, text_mask, keep)
            skips.append(x)
            masks.append(mask)
            x = level["down"](x)
            if mask is not None:  # a coarse frame is valid if either of its two fine frames is
                mask = F.max_pool1d(mask, 2)
                x = x * mask
        for block in self.mid:
            x = block(x, temb, mask, text, text_mask, keep)
        for level in self.ups:
            mask = masks.pop()
            x = _masked(level["up"](x), mask)
            x = torch.cat([x, skips.pop()], dim=1)
            for block in level["blocks"]:
                x = block(x, temb, mask, text, text_mask, keep)
        x = _masked(self.out(x), mask)
        return x[:, :, :T].transpose(1, 2)
