"""`smf train --data DIR --out DIR [--preset small] [--steps N] ... [--resume]`."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..data.batches import TIME_WARP_MAX
from ..diffusion.train import TrainConfig
from .flags import add_config_flags, apply_threads, config_from_args

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
    "lr_schedule": "step (x lr-decay every lr-decay-every) | cosine (to min-lr at --steps) | wsd (constant, then "
                   "cosine to min-lr over the last --decay-steps)",
    "warmup": "steps of linear learning-rate warm-up", "min_lr": "final learning rate of cosine / wsd",
    "decay_steps": "wsd: length of the final decay", "balance": "label balancing power (0 = off, 0.5 = items of a "
    "rare (dataset, content) label drawn sqrt(n_max / n) times per epoch; needs clips.csv)",
    "short_crops": "probability that a training item is cropped to a random 50-100%% of its clip (0 = whole clips)",
    "time_warp": f"probability that a training batch is its motions slowed by a random factor in [1, {TIME_WARP_MAX:g}] "
                 "(0 = never)",
    "time_warp_contents": "which items a slowed batch slows: all, or tempo-free (the contents the corpus's lexicon "
                          "lists as meaning the same when slower: gestures, not run or walk)",
}
_TYPES = {"init_from": str}


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Train a denoiser (x0 prediction, masked MSE, AdamW, EMA, CFG dropout) through "
                                   "accelerate: CPU, one GPU, or `accelerate launch -m stablemofusion.cli.main train`.")
    p.add_argument("--data", type=Path, required=True, help="corpus folder (official HumanML3D layout)")
    p.add_argument("--out", type=Path, required=True, help="run folder: checkpoint/, log.csv, text-cache/")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument("--text-cache", type=Path, default=None, help="text embedding cache folder (default OUT/text-cache)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--threads", type=int, default=None, help="CPU threads for torch (default: torch's choice)")
    ev = p.add_argument_group("self-evaluation", "every --eval-every steps: held-out prompt accuracy and FID on a "
                                                 "fixed validation subset, into OUT/eval.jsonl (`smf curve` draws it)")
    ev.add_argument("--eval-every", type=int, default=0, help="steps between evaluations (0 = never)")
    ev.add_argument("--probe", type=Path, default=None, help="labelled prompt file (e.g. "
                                                             "benchmarks/prompts_heldout_lexicon.jsonl)")
    ev.add_argument("--classifier", type=Path, default=None, help="`smf train-classifier` folder")
    ev.add_argument("--evaluator", type=Path, default=None, help="`smf train-evaluator` folder (FID; optional)")
    ev.add_argument("--fid-items", type=int, default=256, help="validation items for FID (default 256)")
    ev.add_argument("--eval-guidance", type=float, default=None,
                    help="guidance scale of the evaluation samples (default: the model's, 2.5 for a model that names none)")
    add_config_flags(p, TrainConfig, _FLAGS, _TYPES)
    p.add_argument("--stop-after", type=int, default=None, help=argparse.SUPPRESS)  # simulate a kill (tests)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..diffusion.train import check_train_config, train
    from ..core.errors import SMFError

    cfg = config_from_args(TrainConfig, args, _FLAGS)
    check_train_config(cfg)
    apply_threads(args.threads)
    monitor = None
    if args.eval_every:
        if args.eval_every < 0 or args.probe is None or args.classifier is None:
            raise SMFError("--eval-every N needs N > 0, --probe FILE and --classifier DIR")
        from ..diffusion.config import check_guidance
        from ..eval.monitor import MonitorConfig, TrainingMonitor

        check_guidance(args.eval_guidance, "--eval-guidance")
        monitor = TrainingMonitor(args.data, MonitorConfig(args.probe, args.classifier, args.evaluator,
                                                           fid_items=args.fid_items, guidance=args.eval_guidance))
    losses = train(args.data, args.out, cfg, resume=args.resume, stop_after=args.stop_after,
                   progress=not args.no_progress, text_cache=args.text_cache, eval_every=args.eval_every,
                   on_eval=monitor)
    if losses:
        print(f"trained {len(losses)} steps; last loss {losses[-1]:.4f}; checkpoint in {args.out / 'checkpoint'}")
