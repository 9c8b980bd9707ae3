"""The flags `smf generate` and `smf edit` share (sampling, footskate, engine, output), with their defaults
from :mod:`stablemofusion.pipelines.settings`, and the pipeline settings and writers built from them."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_sampling_arguments(p: argparse.ArgumentParser) -> None:
    """--out, --format, --overwrite, --guidance, --steps, --sampler, --seed, --checkpoint, --teacher, --device,
    --engine and the footskate flags."""
    from ..diffusion.engine import ENGINES
    from ..output import FORMATS
    from ..pipelines.settings import FOOTSKATE_MODES, GUIDANCE, SAMPLER, STEPS, STUDENT, STUDENT_EDIT_STEPS
    from .flags import add_teacher_flag

    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--format", default="npy,mp4,bvh", help=f"comma list of {','.join(FORMATS)} (default npy,mp4,bvh)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace files of the same name (default: a free name, NAME-2, NAME-3, ...)")
    p.add_argument("--guidance", type=float, default=None,
                   help=f"classifier-free guidance scale (default: the model's: the scale its config names, else "
                        f"{GUIDANCE}; `smf info` shows it)")
    p.add_argument("--steps", type=int, default=None,
                   help=f"sampling steps (default: the model's: {STEPS}, a distilled student its own count; editing "
                        f"with a student at least {STUDENT_EDIT_STEPS})")
    p.add_argument("--sampler", default=None,
                   help=f"sampler name (default: the model's: {SAMPLER}, a distilled student {STUDENT})")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--checkpoint", type=Path, default=None, help="checkpoint or run folder (default: shipped model)")
    add_teacher_flag(p)
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    p.add_argument("--threads", type=int, default=None,
                   help="CPU threads for torch (default: OMP_NUM_THREADS if set, else the idle cores: the cores less "
                        "the 1-minute load average, at least 1)")
    p.add_argument("--engine", default="auto", choices=("auto",) + ENGINES,
                   help="denoising engine (default auto: CUDA graphs on a GPU, the precomputed solver loop on a CPU; "
                        "docs/inference.md)")
    p.add_argument("--footskate", default="off", choices=FOOTSKATE_MODES,
                   help="footskate cleanup: off, post (after sampling) or loop (inside the last denoising steps)")
    add_contact_arguments(p)


def add_contact_arguments(p: argparse.ArgumentParser) -> None:
    """--contacts, --vgrf-model, --underpressure: how the footskate cleanup finds contacts."""
    p.add_argument("--contacts", default="kinematic", choices=("kinematic", "vgrf"),
                   help="contact route for the cleanup (vgrf needs --vgrf-model or --underpressure)")
    p.add_argument("--vgrf-model", type=Path, default=None,
                   help="distilled 22-joint vGRF model (.safetensors): adds the vGRF loss (non-commercial)")
    p.add_argument("--underpressure", type=Path, default=None,
                   help="UnderPressure pretrained.tar used directly as vGRF model (non-commercial, slower)")


def footskate_options_from_args(args):
    """FootskateOptions from the flags of :func:`add_contact_arguments`."""
    from ..footskate import CleanupConfig, FootskateOptions
    from .footskate import vgrf_model_from_args

    model = None
    if args.vgrf_model is not None or args.underpressure is not None or args.contacts == "vgrf":
        model = vgrf_model_from_args(args.vgrf_model, args.underpressure, required=True)
    return FootskateOptions(config=CleanupConfig(contacts=args.contacts), vgrf_model=model)


def sampling_kwargs(args) -> dict:
    """The pipeline keywords of :func:`add_sampling_arguments`' flags."""
    options = footskate_options_from_args(args) if args.footskate != "off" else None
    return dict(guidance_scale=args.guidance, steps=args.steps, sampler=args.sampler, seed=args.seed,
                footskate=args.footskate, footskate_options=options, engine=args.engine)


def idle_threads() -> int:
    """The cores this process may run on less the 1-minute load average (other processes' running threads),
    at least 1: torch threads that do not fight a busy core (on this project's 2-core CPU with one core busy,
    `smf generate` took 19.5 s with two threads and 6.3 s with one; idle, 5.7 s either way)."""
    import os

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    try:
        busy = os.getloadavg()[0]
    except OSError:  # no load average on this platform
        busy = 0.0
    return max(1, min(cores, int(cores - busy + 0.5)))


def set_threads(args) -> None:
    """torch's CPU threads from ``--threads``, else OMP_NUM_THREADS when set, else :func:`idle_threads`."""
    import os

    import torch

    from .flags import apply_threads

    if args.threads is not None or "OMP_NUM_THREADS" in os.environ:
        apply_threads(args.threads)
    else:
        torch.set_num_threads(min(torch.get_num_threads(), idle_threads()))


def load_pipeline(args):
    from ..pipeline import MotionPipeline

    set_threads(args)
    return MotionPipeline.from_pretrained(args.checkpoint, teacher=args.teacher, device=args.device, engine=args.engine)


def output_meta(args, pipe, *, edit: bool = False) -> dict:
    """What the JSON output records of how a motion was made (the guidance, steps and sampler ``pipe`` used;
    ``edit``: for an edit)."""
    from ..pipelines.settings import Settings

    s = pipe.settings(Settings(args.guidance, args.steps, args.sampler), edit=edit)
    return {"sampler": s.sampler, "steps": s.steps, "guidance": s.guidance_scale, "student": pipe.student}
