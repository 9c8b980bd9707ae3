"""`smf train-classifier --data DIR --out DIR [--steps N]`: the content/style motion classifier."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..eval.classifier import ClassifierTrainConfig
from .flags import add_config_flags, config_from_args

_HELP = {"steps": "optimisation steps", "batch_size": "motions per batch", "lr": "AdamW learning rate",
         "weight_decay": "AdamW weight decay", "seed": "random seed"}


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Train a content and style classifier on the real train-split motions of a "
                                   "labelled corpus (clips.csv); prints its accuracy on the val and test splits.")
    p.add_argument("--data", type=Path, required=True, help="labelled corpus folder (from `smf prepare bandai`)")
    p.add_argument("--out", type=Path, required=True, help="classifier folder to write")
    p.add_argument("--no-progress", action="store_true")
    add_config_flags(p, ClassifierTrainConfig, _HELP)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..core.errors import SMFError
    from ..eval.classifier import train_classifier

    cfg = config_from_args(ClassifierTrainConfig, args, _HELP)
    if cfg.steps < 1 or cfg.batch_size < 1:
        raise SMFError("--steps and --batch-size must be at least 1")
    if not args.data.is_dir():
        raise SMFError(f"no such corpus folder: {args.data}")
    summary = train_classifier(args.data, args.out, cfg, progress=not args.no_progress)
    print(json.dumps({"out": str(args.out), "accuracy": summary["accuracy"]}))
