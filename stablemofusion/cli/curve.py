"""`smf curve RUN --out curve.png`: a training run's learning curve (its self-evaluations and loss) as a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name, help="draw a training run's learning curve (probe accuracy, FID, loss) as a PNG",
                       description="Plot RUN/eval.jsonl (`smf train --eval-every`) and RUN/log.csv: held-out probe "
                                   "content and style accuracy and validation FID against steps and against "
                                   "training wall time, and the smoothed loss.")
    p.add_argument("run", type=Path, help="training run folder (log.csv, eval.jsonl)")
    p.add_argument("--out", type=Path, required=True, help="PNG file to write")
    p.add_argument("--title", default=None, help="figure title (default: the run folder's name)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..errors import SMFError
    from ..eval.curve import draw_curve, read_run

    if args.out.suffix.lower() != ".png":
        raise SMFError(f"--out must be a .png file, got {args.out}")
    evals, log = read_run(args.run)
    draw_curve(evals, log, args.out, args.title or args.run.name)
    last = evals[-1] if evals else None
    print(f"wrote {args.out} ({len(evals)} evaluations, {len(log['step'])} logged steps"
          + (f"; last at step {last['step']}" if last else "") + ")")
