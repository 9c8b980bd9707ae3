"""`smf train --data DIR --out DIR [--preset small] [--steps N] ... [--resume]`."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..diffusion.train import TrainConfig
from .flags import add_config_flags, config_from_args

_FLAGS = {  # TrainConfig field -> help
    "preset": "model preset (see `smf info`)", "steps": "total optimisation steps", "batch_size": "batch per device",
    "lr": "AdamW learning rate", "weight_decay": "AdamW weight decay", "lr_decay": "LR factor every --lr-decay-every",
    "lr_decay_every": "steps between LR decays", "grad_clip": "gradient norm clip", "ema_decay": "EMA decay",
    "cond_drop": "fraction of samples trained without text (CFG)", "seed": "random seed",
    "mixed_precision": "no | fp16 | bf16 (GPU)", "text_encoder": "minilm or clip:<folder>",
    "checkpoint_every": "steps between checkpoints", "max_frames": "longest training crop (frames)",
    "min_frames": "shortest motion used (frames; default 40 at 20 fps)", "feat_bias": "root/contact std divisor",
    "bucket": "group similar lengths: sort runs of BUCKET batches by length (0 = off)",
    "text_augment": "probability that a training caption is perturbed (word dropout, synonym swap, typos, case)",
    "init_from": "start from the weights of this checkpoint, run or exported folder (fine-tuning)",
    "compile": "torch.compile the training forward (pays on a GPU)",
}
_TYPES = {"init_from": str}


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name, help="train a diffusion denoiser on a HumanML3D-layout corpus",
                       description="Train a denoiser (x0 prediction, masked MSE, AdamW, EMA, CFG dropout) through "
                                   "accelerate: CPU, one GPU, or `accelerate launch -m stablemofusion.cli.main train`.")
    p.add_argument("--data", type=Path, required=True, help="corpus folder (official HumanML3D layout)")
    p.add_argument("--out", type=Path, required=True, help="run folder: checkpoint/, log.csv, text-cache/")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument("--text-cache", type=Path, default=None, help="text embedding cache folder (default OUT/text-cache)")
    p.add_argument("--no-progress", action="store_true")
    add_config_flags(p, TrainConfig, _FLAGS, _TYPES)
    p.add_argument("--stop-after", type=int, default=None, help=argparse.SUPPRESS)  # simulate a kill (tests)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..diffusion.train import train
    from ..errors import SMFError

    cfg = config_from_args(TrainConfig, args, _FLAGS)
    if cfg.steps < 1 or cfg.batch_size < 1:
        raise SMFError("--steps and --batch-size must be at least 1")
    if cfg.mixed_precision not in ("no", "fp16", "bf16"):
        raise SMFError(f"--mixed-precision must be no, fp16 or bf16, not {cfg.mixed_precision!r}")
    losses = train(args.data, args.out, cfg, resume=args.resume, stop_after=args.stop_after,
                   progress=not args.no_progress, text_cache=args.text_cache)
    if losses:
        print(f"trained {len(losses)} steps; last loss {losses[-1]:.4f}; checkpoint in {args.out / 'checkpoint'}")
