"""Sampler registry: diffusers schedulers by name, set up for an x0-predicting model.

Names: ``ddpm``, ``ddim``, ``pndm``, ``deis``, ``dpmsolver++`` (ODE), ``sde-dpmsolver++``; append
``-karras`` for Karras sigmas where the scheduler supports them (deis and the DPM-Solvers).
"""

from __future__ import annotations

from dataclasses import asdict

import torch
from diffusers import (DDIMScheduler, DDPMScheduler, DEISMultistepScheduler, DPMSolverMultistepScheduler,
                       PNDMScheduler)

from ..errors import SMFError
from .schedule import ScheduleConfig

_BASE = {
    "ddpm": (DDPMScheduler, {"clip_sample": False}, False),
    "ddim": (DDIMScheduler, {"clip_sample": False, "set_alpha_to_one": False}, False),
    "pndm": (PNDMScheduler, {"skip_prk_steps": True, "set_alpha_to_one": False}, False),
    "deis": (DEISMultistepScheduler, {}, True),
    "dpmsolver++": (DPMSolverMultistepScheduler, {"algorithm_type": "dpmsolver++"}, True),
    "sde-dpmsolver++": (DPMSolverMultistepScheduler, {"algorithm_type": "sde-dpmsolver++"}, True),
}
DEFAULT_SAMPLER = "sde-dpmsolver++-karras"


def sampler_names() -> list[str]:
    """Every valid sampler name."""
    names = []
    for name, (_, _, karras) in _BASE.items():
        names += [name] + ([f"{name}-karras"] if karras else [])
    return names


def make_sampler(name: str, schedule: ScheduleConfig | None = None):
    """A fresh diffusers scheduler for sampler ``name`` over the training schedule.

    Models predict x0; schedulers that accept ``prediction_type='sample'`` get it, PNDM (epsilon only) gets
    epsilon and :func:`model_output_for` converts.
    """
    base, karras = (name[: -len("-karras")], True) if name.endswith("-karras") else (name, False)
    if base not in _BASE:
        raise SMFError(f"unknown sampler {name!r}; known: {', '.join(sampler_names())}")
    cls, extra, supports_karras = _BASE[base]
    if karras and not supports_karras:
        raise SMFError(f"sampler {base!r} has no Karras-sigma variant; use one of: "
                       + ", ".join(n for n in sampler_names() if n.endswith("-karras")))
    cfg = asdict(schedule or ScheduleConfig())
    cfg["prediction_type"] = "epsilon" if cls is PNDMScheduler else "sample"
    if karras:
        extra = {**extra, "use_karras_sigmas": True}
    return cls(**cfg, **extra)


def model_output_for(scheduler, x0: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor | int) -> torch.Tensor:
    """What ``scheduler.step`` expects from an x0 prediction: x0 itself, or epsilon for PNDM."""
    if scheduler.config.prediction_type == "sample":
        return x0
    ab = scheduler.alphas_cumprod.to(x_t.device)[t].to(x_t.dtype)
    return (x_t - ab.sqrt() * x0) / (1 - ab).sqrt()
