"""The denoiser architectures by name: importing this module registers each (CondUNet1D, DiT, RetNet) in
:data:`~stablemofusion.models.base.DENOISERS`; :func:`build_denoiser` makes one from its config."""

from __future__ import annotations

from . import dit, retnet, unet1d  # noqa: F401  (each registers its architecture)
from .base import DENOISERS, Denoiser, ModelConfig
from ..core.errors import SMFError


def build_denoiser(config: ModelConfig) -> Denoiser:
    """Instantiate the denoiser named by ``config.arch`` with ``config.options``."""
    if config.arch not in DENOISERS:
        raise SMFError(f"unknown architecture {config.arch!r}; known: {', '.join(sorted(DENOISERS))}")
    cls = DENOISERS[config.arch]
    try:
        arch_cfg = cls.config_class(**config.options)
    except TypeError as e:
        raise SMFError(f"bad options for {config.arch}: {e}") from None
    model = cls(arch_cfg, config.motion_dim, config.text)
    if config.guidance:
        model.init_guidance_condition()
    return model
