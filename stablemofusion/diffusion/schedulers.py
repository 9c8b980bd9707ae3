"""Sampler registry: diffusers schedulers by name, set up for an x0-predicting model, with their facts.

Names: ``ddpm``, ``ddim``, ``pndm``, ``deis``, ``euler``, ``dpmsolver++`` (ODE), ``sde-dpmsolver++``, ``lcm``
(multistep consistency sampling: the few-step students of ``smf distil``); append ``-karras`` for Karras
sigmas where the scheduler supports them. Each name's facts (stochastic or not, whether
its step takes its noise as a tensor, whether the fast engine has it) live in :data:`SAMPLERS`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import torch

from ..core.errors import SMFError
from .schedule import ScheduleConfig


@dataclass(frozen=True)
class SamplerSpec:
    """One base sampler: the diffusers scheduler class and options, and what the sampling loop must know.

    ``stochastic``: it adds fresh noise at every step; ``step_noise``: its ``step`` takes that noise as a
    tensor (``variance_noise``), so an item's noise can come from its own seed; ``karras``: it has a
    ``-karras`` variant; ``fast``: :mod:`.solvers` has it as a precomputed-coefficient update (the engine)."""

    scheduler: str
    options: dict[str, Any] = field(default_factory=dict)
    karras: bool = False
    stochastic: bool = False
    step_noise: bool = False
    fast: bool = False


SAMPLERS: dict[str, SamplerSpec] = {
    "ddpm": SamplerSpec("DDPMScheduler", {"clip_sample": False}, stochastic=True),
    "ddim": SamplerSpec("DDIMScheduler", {"clip_sample": False, "set_alpha_to_one": False}, fast=True),
    "pndm": SamplerSpec("PNDMScheduler", {"skip_prk_steps": True, "set_alpha_to_one": False}),
    "deis": SamplerSpec("DEISMultistepScheduler", karras=True),
    "euler": SamplerSpec("EulerDiscreteScheduler", karras=True, fast=True),
    "dpmsolver++": SamplerSpec("DPMSolverMultistepScheduler", {"algorithm_type": "dpmsolver++"}, karras=True,
                               fast=True),
    "sde-dpmsolver++": SamplerSpec("DPMSolverMultistepScheduler", {"algorithm_type": "sde-dpmsolver++"},
                                   karras=True, stochastic=True, step_noise=True, fast=True),
    # consistency sampling (Song et al. 2023; LCM): predict x0 through the boundary-condition scalings, re-noise
    # to the next timestep of the CONSISTENCY_GRID-point skip schedule the student was distilled on
    "lcm": SamplerSpec("LCMScheduler", {"original_inference_steps": 50, "timestep_scaling": 10.0,
                                        "set_alpha_to_one": False}, stochastic=True, fast=True),
}
CONSISTENCY_GRID = SAMPLERS["lcm"].options["original_inference_steps"]
TIMESTEP_SCALING = SAMPLERS["lcm"].options["timestep_scaling"]
SIGMA_DATA = 0.5  # LCM's boundary-condition constant (diffusers' LCMScheduler)
EPSILON_ONLY = frozenset({"PNDMScheduler"})  # schedulers without prediction_type='sample'


def sampler_names() -> list[str]:
    """Every valid sampler name."""
    names = []
    for name, spec in SAMPLERS.items():
        names += [name] + ([f"{name}-karras"] if spec.karras else [])
    return names


def parse_sampler(name: str) -> tuple[str, SamplerSpec, bool]:
    """(base name, its spec, Karras sigmas?) of a sampler name; SMFError for an unknown one."""
    base, karras = (name[: -len("-karras")], True) if name.endswith("-karras") else (name, False)
    if base not in SAMPLERS:
        raise SMFError(f"unknown sampler {name!r}; known: {', '.join(sampler_names())}")
    spec = SAMPLERS[base]
    if karras and not spec.karras:
        raise SMFError(f"sampler {base!r} has no Karras-sigma variant; use one of: "
                       + ", ".join(n for n in sampler_names() if n.endswith("-karras")))
    return base, spec, karras


def sampler_spec(name: str) -> SamplerSpec:
    return parse_sampler(name)[1]


def make_sampler(name: str, schedule: ScheduleConfig | None = None):
    """A fresh diffusers scheduler for sampler ``name`` over the training schedule.

    Models predict x0; schedulers that accept ``prediction_type='sample'`` get it, PNDM (epsilon only) gets
    epsilon and :func:`model_output_for` converts.
    """
    import diffusers

    _, spec, karras = parse_sampler(name)
    cfg = asdict(schedule or ScheduleConfig())
    cfg["prediction_type"] = "epsilon" if spec.scheduler in EPSILON_ONLY else "sample"
    extra = {**spec.options, **({"use_karras_sigmas": True} if karras else {})}
    return getattr(diffusers, spec.scheduler)(**cfg, **extra)


def model_output_for(scheduler, x0: torch.Tensor, x_t: torch.Tensor, t: torch.Tensor | int) -> torch.Tensor:
    """What ``scheduler.step`` expects from an x0 prediction: x0 itself, or epsilon for PNDM."""
    if scheduler.config.prediction_type == "sample":
        return x0
    ab = scheduler.alphas_cumprod.to(x_t.device)[t].to(x_t.dtype)
    return (x_t - ab.sqrt() * x0) / (1 - ab).sqrt()
