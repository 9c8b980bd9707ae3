"""`smf ablate samplers|arch ...`: the paper's sampler and architecture tables -> markdown + JSON."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict, replace
from pathlib import Path

from .evaluate import add_eval_args

DEFAULT_GRID = "5,10,20,50"
DEFAULT_SAMPLERS = ("ddpm,ddim,pndm,deis-karras,dpmsolver++-karras,sde-dpmsolver++-karras")


def add_parser(sub, name: str) -> None:
    from .flags import add_teacher_flag

    p = sub.add_parser(name,
                       description="Reproduce the paper's sampler table (min. steps within 5% of each sampler's "
                                   "best FID and top-3) and architecture table (each preset trained alike).")
    kinds = p.add_subparsers(dest="kind", metavar="KIND", required=True)
    s = kinds.add_parser("samplers", help="sampler x steps table for one checkpoint")
    s.add_argument("--checkpoint", type=Path, default=None, help="checkpoint or run folder (default: shipped model)")
    add_teacher_flag(s)
    s.add_argument("--samplers", default=DEFAULT_SAMPLERS, help=f"comma list (default {DEFAULT_SAMPLERS})")
    s.add_argument("--grid", default=DEFAULT_GRID, help=f"comma list of step counts (default {DEFAULT_GRID})")
    s.add_argument("--ddpm-steps", default="1000", help="extra step counts for ddpm (default 1000; '' = none)")
    s.add_argument("--out", type=Path, required=True, help="JSON results file (.md beside it)")
    add_eval_args(s)
    s.set_defaults(func=run_samplers)
    a = kinds.add_parser("arch", help="train and evaluate each architecture preset")
    a.add_argument("--presets", default=None, help="comma list (default: the 7 ablation presets)")
    a.add_argument("--train-steps", type=int, default=2000, help="training steps per preset (default 2000)")
    a.add_argument("--batch-size", type=int, default=64, help="training batch (default 64)")
    a.add_argument("--bucket", type=int, default=16, help="length bucketing of training batches (default 16)")
    a.add_argument("--runs", type=Path, required=True, help="folder for the training runs (one per preset)")
    a.add_argument("--text-cache", type=Path, default=None, help="shared text embedding cache")
    a.add_argument("--out", type=Path, required=True, help="JSON results file (.md beside it)")
    add_eval_args(a)
    a.set_defaults(func=run_arch)


def _ints(text: str, what: str) -> list[int]:
    from ..core.errors import SMFError

    try:
        vals = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise SMFError(f"{what} must be a comma list of integers, got {text!r}") from None
    if any(v < 1 for v in vals):
        raise SMFError(f"{what} must be positive, got {text!r}")
    return vals


def _write(out: Path, result: dict, md: str) -> None:
    from ..core.io import write_text

    write_text(out, json.dumps(result, indent=2, default=float) + "\n")
    write_text(out.with_suffix(".md"), md + "\n")


def run_samplers(args: argparse.Namespace) -> None:
    from ..diffusion.schedulers import make_sampler
    from ..core.errors import SMFError
    from ..eval.ablation import ablate_samplers, sampler_markdown
    from ..pipelines.motion_pipeline import MotionPipeline
    from ..core.settings import Settings
    from .evaluate import eval_config, load_embedder, rigid_config

    if not args.data.is_dir():
        raise SMFError(f"no such corpus folder: {args.data}")
    samplers = [s.strip() for s in args.samplers.split(",") if s.strip()]
    if not samplers:
        raise SMFError("--samplers is empty")
    grid = _ints(args.grid, "--grid")
    extra = _ints(args.ddpm_steps, "--ddpm-steps") if args.ddpm_steps else []
    pipe = MotionPipeline.from_pretrained(args.checkpoint, backend="torch", teacher=args.teacher, device=args.device,
                                          rigid=rigid_config(args))
    for s in samplers:
        make_sampler(s, pipe.schedule)  # unknown names fail before any work
    cfg = eval_config(args, mm_captions=0 if args.mm_captions is None else args.mm_captions)
    # the model's guidance where --guidance leaves it (the samplers and steps are what this ablation varies)
    cfg = replace(cfg, guidance_scale=pipe.settings(Settings(guidance_scale=cfg.guidance_scale)).guidance_scale)
    embedder = load_embedder(args, pipe)
    full = {s: sorted(set(grid + (extra if s == "ddpm" else []))) for s in samplers}
    result = ablate_samplers(pipe, embedder, args.data, cfg, full, progress=not args.no_progress)
    result["config"] = asdict(cfg)
    md = sampler_markdown(result)
    _write(args.out, result, md)
    print(md)


def run_arch(args: argparse.Namespace) -> None:
    from ..diffusion.train import TrainConfig
    from ..core.errors import SMFError
    from ..eval.ablation import ARCH_PRESETS, ablate_arch, arch_markdown
    from ..models.presets import get_preset
    from ..core.settings import model_defaults
    from .evaluate import eval_config, load_embedder, rigid_config

    if not args.data.is_dir():
        raise SMFError(f"no such corpus folder: {args.data}")
    presets = [p.strip() for p in args.presets.split(",")] if args.presets else list(ARCH_PRESETS)
    for p in presets:
        get_preset(p, motion_dim=263, text_dim=384)  # unknown presets fail early
    if args.train_steps < 1 or args.batch_size < 1:
        raise SMFError("--train-steps and --batch-size must be positive")
    cfg = eval_config(args, mm_captions=0 if args.mm_captions is None else args.mm_captions)
    # freshly trained presets name no guidance: the package's default where --guidance leaves it
    cfg = replace(cfg, guidance_scale=model_defaults(None, cfg.guidance_scale)[0])
    embedder = load_embedder(args)
    tcfg = TrainConfig(steps=args.train_steps, batch_size=args.batch_size, bucket=args.bucket,
                       checkpoint_every=max(args.train_steps // 4, 1), seed=args.seed)
    table = ablate_arch(args.data, args.runs, embedder, cfg, presets, tcfg, progress=not args.no_progress,
                        text_cache=args.text_cache, rigid=rigid_config(args))
    md = arch_markdown(table)
    _write(args.out, {"config": asdict(cfg), "train": asdict(tcfg), "table": table}, md)
    print(md)
