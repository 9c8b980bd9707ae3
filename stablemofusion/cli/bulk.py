"""`smf bulk PROMPTS.txt --out DIR [--workers N] [--address ADDR]`: many prompts into a sharded Parquet dataset on a
Ray cluster (docs/bulk.md); the same command again resumes a run that stopped."""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path


def add_parser(sub, name: str) -> None:
    from ..core.limits import BATCH_SIZE, ENGINES, FOOTSKATE, FOOTSKATE_MODES, PORTABLE_ENGINE
    from .flags import add_teacher_flag

    p = sub.add_parser(name, description="Generate one motion per line of a prompts file into a dataset folder of "
                                         "Parquet shards, on the workers of a Ray cluster (a local one by default). "
                                         "The motions are those of `smf generate --prompts FILE` with the same "
                                         "--seed and --batch-size; run the same command again to resume.")
    p.add_argument("prompts", type=Path, help="file with one prompt per line")
    p.add_argument("--out", type=Path, required=True, help="dataset folder (new, empty, or a run to resume)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first batch; batch k uses seed + k")
    p.add_argument("--seconds", type=float, default=None, help="length of each motion (default: predicted from its text)")
    p.add_argument("--batch-size", type=int, default=BATCH_SIZE, help="prompts generated together")
    p.add_argument("--shard-batches", type=int, default=8, help="batches in one Parquet shard")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes, one CPU each (default: the local cluster's CPUs)")
    p.add_argument("--address", default=None,
                   help="a running Ray cluster's address ('auto': the one this machine belongs to; default: start a "
                        "local one for this run)")
    p.add_argument("--threads", type=int, default=1, help="threads of each worker's model")
    p.add_argument("--checkpoint", type=Path, default=None, help="checkpoint or run folder (default: shipped model)")
    add_teacher_flag(p)
    p.add_argument("--engine", default="auto", choices=("auto",) + ENGINES + (PORTABLE_ENGINE,),
                   help=f"denoising engine (default auto: as `smf generate`; {PORTABLE_ENGINE} without PyTorch)")
    p.add_argument("--guidance", type=float, default=None, help="classifier-free guidance scale (default: the model's)")
    p.add_argument("--steps", type=int, default=None, help="sampling steps (default: the model's)")
    p.add_argument("--footskate", default=FOOTSKATE, choices=FOOTSKATE_MODES, help="footskate cleanup")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import os

    from .. import __version__
    from ..core.errors import SMFError
    from ..core.limits import check_seconds
    from .generate import read_prompts_file
    from .options import check_sampling, choose_engine, load_pipeline

    check_seconds(args.seconds, "--seconds")
    check_sampling(args)
    if args.workers is not None and args.workers < 1:
        raise SMFError(f"--workers is at least 1, got {args.workers}")
    if args.threads < 1:
        raise SMFError(f"--threads is at least 1, got {args.threads}")
    from ..bulk import ray_run  # the ray extra: `smf` answers its absence in one line
    from ..bulk.dataset import BulkPlan
    choose_engine(args)
    prompts = read_prompts_file(args.prompts)
    sampling = (("guidance_scale", args.guidance), ("steps", args.steps), ("footskate", args.footskate),
                ("engine", args.engine))
    what = "shipped model" if args.checkpoint is None else str(args.checkpoint)
    plan = BulkPlan(tuple(prompts), args.seed, args.batch_size, args.shard_batches, args.seconds, sampling,
                    f"{what}{' (teacher)' if args.teacher else ''}, stablemofusion {__version__}")
    # absolute paths: a worker of a cluster runs elsewhere
    checkpoint = None if args.checkpoint is None else args.checkpoint.resolve()
    model_args = argparse.Namespace(checkpoint=checkpoint, teacher=args.teacher, engine=args.engine,
                                    threads=args.threads, device="cpu", adapter=None)
    load = functools.partial(load_pipeline, model_args)
    load()  # here first: a model that does not load is one line, before any worker starts
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # nothing leaves this machine
    summary = ray_run.run(plan, args.out.resolve(), load, workers=args.workers, address=args.address,
                          progress=not args.quiet)
    if summary["out_of_domain"]:
        print(f"smf: warning: {summary['out_of_domain']} of {summary['motions']} prompts are unlike anything this model "
              "was trained on (the dataset's out_of_domain column names them)", file=sys.stderr)
    print(json.dumps({"out": str(args.out), **summary}))
    sys.stdout.flush()
