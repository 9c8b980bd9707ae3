"""`smf distil --teacher MODEL --out RUN [--data CORPUS] [--steps N] ... [--resume]`: a few-step student."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..diffusion.config import DistilConfig
from .flags import add_config_flags, apply_threads, config_from_args

_FLAGS = {  # DistilConfig field -> help
    "teacher": "the teacher: a checkpoint, run or exported model folder (e.g. the shipped default model)",
    "method": "consistency (LCM consistency distillation) | regression (the student's sample pulled towards the "
              "teacher's deterministic sample from the same noise; start it from a consistency student)",
    "init_from": "a student folder to start from (default: the teacher's weights)",
    "teacher_sampler": "regression: the teacher's deterministic sampler", "teacher_steps": "regression: its steps",
    "length_mix": "regression: fraction of steps sampled at one length drawn uniformly in [min, max] frames "
                  "instead of the clips' lengths",
    "steps": "total distillation steps", "batch_size": "batch", "lr": "AdamW learning rate (constant after warm-up)",
    "weight_decay": "AdamW weight decay", "warmup": "steps of linear learning-rate warm-up",
    "grad_clip": "gradient norm clip", "target_decay": "EMA decay of the target network (the saved weights)",
    "guidance_min": "smallest guidance scale drawn per item", "guidance_max": "largest guidance scale drawn per item",
    "grid": "points of the skip schedule (the lcm sampler's: 50)", "loss": "l2 | huber (pseudo-Huber)",
    "huber_c": "pseudo-Huber constant", "cond_drop": "fraction of items distilled without text",
    "dropout": "keep the student's dropout active while distilling (default off: the targets have none)",
    "seed": "random seed", "mixed_precision": "no | fp16 | bf16", "checkpoint_every": "steps between checkpoints",
    "bucket": "group similar lengths: sort runs of BUCKET batches by length (0 = off)",
    "max_frames": "longest training crop (frames; default the teacher's)",
    "min_frames": "shortest motion used (frames; default the teacher's)",
    "sample_steps": "the student's default sampling step count (recorded in its checkpoint)",
    "guidance_lr_scale": "learning rate of the guidance-scale embedding, as a multiple of --lr",
}


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Consistency distillation (LCM) of a teacher into a student that samples in a few "
                                   "steps with one forward per step (the guidance scale is an input), or regression "
                                   "on the teacher's samples (--method regression); docs/inference.md, 'Few-step "
                                   "student'. Resumable with --resume.")
    p.add_argument("--data", type=Path, required=True, help="corpus folder (the teacher's training corpus)")
    p.add_argument("--out", type=Path, required=True, help="run folder: checkpoint/, log.csv, text-cache/")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument("--text-cache", type=Path, default=None, help="text embedding cache folder (default OUT/text-cache)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--threads", type=int, default=None, help="CPU threads for torch (default: torch's choice)")
    add_config_flags(p, DistilConfig, _FLAGS, {"teacher": str, "init_from": str})
    p.add_argument("--stop-after", type=int, default=None, help=argparse.SUPPRESS)  # simulate a kill (tests)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..diffusion.distil import check_distil_config, distil

    cfg = config_from_args(DistilConfig, args, _FLAGS)
    check_distil_config(cfg)
    apply_threads(args.threads)
    losses = distil(args.data, args.out, cfg, resume=args.resume, stop_after=args.stop_after,
                    progress=not args.no_progress, text_cache=args.text_cache)
    if losses:
        print(f"distilled {len(losses)} steps; last loss {losses[-1]:.4f}; student in {args.out / 'checkpoint'}")
