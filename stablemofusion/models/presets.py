"""Named model configurations: the paper's UNet, a small CPU one, and the architecture-ablation variants."""

from __future__ import annotations

from dataclasses import asdict

from ..core.errors import SMFError
from .base import ModelConfig, TextConfig
from .dit import DiTConfig
from .retnet import RetNetConfig
from .unet1d import UNetConfig

_SMALL_UNET = dict(base_dim=64, dim_mults=(1, 2, 2, 2), blocks_per_level=1, attn_heads=4, time_dim=128)
_SMALL_TEXT = TextConfig(latent=256, layers=4, heads=4, ff=512)
_SMALL_SENTENCE_TEXT = TextConfig(latent=256, layers=4, heads=4, ff=512, sentence=True)

# name -> (architecture, architecture options, text options, what it is)
PRESETS: dict[str, tuple[str, object, TextConfig, str]] = {
    "paper": ("unet", UNetConfig(base_dim=512, dim_mults=(2, 2, 2, 2)), TextConfig(),
              "CondUNet1D as in the paper (base 512, multipliers 2,2,2,2)"),
    "small": ("unet", UNetConfig(**_SMALL_UNET), _SMALL_TEXT, "CondUNet1D sized for CPU training and sampling"),
    "small-sentence": ("unet", UNetConfig(**_SMALL_UNET), _SMALL_SENTENCE_TEXT,
                       "small + the frozen encoder's sentence embedding as a global condition"),
    # architecture ablation at a size that trains on a CPU (paper Table 4 at our scale)
    "unet-baseline": ("unet", UNetConfig(**_SMALL_UNET, cross_attention=False, groupnorm_tweak=False,
                                         mask_padding=False), _SMALL_TEXT, "UNet baseline: pooled text added to time"),
    "unet-xattn": ("unet", UNetConfig(**_SMALL_UNET, groupnorm_tweak=False, mask_padding=False), _SMALL_TEXT,
                   "UNet + cross-attention"),
    "unet-xattn-gn": ("unet", UNetConfig(**_SMALL_UNET), _SMALL_TEXT, "UNet + cross-attention + GroupNorm tweak"),
    "dit": ("dit", DiTConfig(dim=128, layers=4, heads=4, cross_attention=False), _SMALL_TEXT,
            "DiT baseline: text tokens concatenated"),
    "dit-xattn": ("dit", DiTConfig(dim=128, layers=4, heads=4, cross_attention=True), _SMALL_TEXT,
                  "DiT + cross-attention"),
    "retnet": ("retnet", RetNetConfig(dim=128, layers=4, heads=4, cross_attention=False), _SMALL_TEXT,
               "RetNet baseline: timestep and text tokens concatenated"),
    "retnet-xattn": ("retnet", RetNetConfig(dim=128, layers=4, heads=4, cross_attention=True), _SMALL_TEXT,
                     "RetNet + cross-attention"),
    "tiny": ("unet", UNetConfig(base_dim=16, dim_mults=(1, 2), attn_heads=2, time_dim=32, dropout=0.0),
             TextConfig(latent=32, layers=1, heads=2, ff=64), "a minute UNet for tests and debugging"),
    "dit-paper": ("dit", DiTConfig(dim=512, layers=8, heads=8, cross_attention=True), TextConfig(),
                  "DiT + cross-attention, paper-scale width"),
    "retnet-paper": ("retnet", RetNetConfig(dim=512, layers=8, heads=8, cross_attention=True), TextConfig(),
                     "RetNet + cross-attention, paper-scale width"),
}


def get_preset(name: str, motion_dim: int = 263, text_dim: int = 384) -> ModelConfig:
    """The ModelConfig of preset ``name`` for features of width ``motion_dim`` and a text encoder of ``text_dim``."""
    if name not in PRESETS:
        raise SMFError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}")
    arch, options, text, _ = PRESETS[name]
    text = TextConfig(**{**asdict(text), "in_dim": text_dim})
    return ModelConfig(arch=arch, motion_dim=motion_dim, text=text, options=asdict(options))


def describe(name: str) -> str:
    return PRESETS[name][3]
