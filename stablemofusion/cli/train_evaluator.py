"""`smf train-evaluator --data DIR --out DIR [--steps N] ...`: the contrastive text/motion evaluator."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..eval.train_evaluator import EvaluatorTrainConfig
from .flags import add_config_flags, config_from_args

_HELP = {"steps": "optimisation steps", "batch_size": "pairs per batch", "lr": "AdamW learning rate",
         "weight_decay": "AdamW weight decay", "temperature": "InfoNCE temperature on distances",
         "grad_clip": "gradient norm clip", "seed": "random seed", "text_encoder": "minilm or clip:<folder>",
         "max_frames": "longest crop (frames)", "bucket": "group similar lengths (0 = off)",
         "eval_every": "steps between validation R-precision checks"}


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Train the T2M-style evaluator (temporal conv + BiGRU motion encoder, frozen "
                                   "language model + BiGRU text encoder, 512-d) contrastively on the train split.")
    p.add_argument("--data", type=Path, required=True, help="corpus folder (HumanML3D layout)")
    p.add_argument("--out", type=Path, required=True, help="evaluator folder to write")
    p.add_argument("--text-cache", type=Path, default=None, help="text embedding cache folder")
    p.add_argument("--no-progress", action="store_true")
    add_config_flags(p, EvaluatorTrainConfig, _HELP)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..eval.train_evaluator import train_evaluator

    cfg = config_from_args(EvaluatorTrainConfig, args, _HELP)
    meta = train_evaluator(args.data, args.out, cfg, progress=not args.no_progress, text_cache=args.text_cache)
    last = meta["validation"][-1] if meta["validation"] else {}
    print(json.dumps({"out": str(args.out), "final_loss": round(meta["final_loss"], 4), **last}))
