"""`smf curve RUN --out curve.png`: a training run's learning curve (its self-evaluations and loss) as a PNG;
`smf curve RUN RUN ... --out compare.png`: several runs (recipe arms) overlaid, with a table of their evaluations."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Plot RUN/eval.jsonl (`smf train --eval-every`) and RUN/log.csv: held-out probe "
                                   "content and style accuracy and validation FID against steps and against "
                                   "training wall time, and the smoothed loss. With several runs: their evaluations "
                                   "overlaid (one line per run) and printed as a markdown table.")
    p.add_argument("run", type=Path, nargs="+", help="training run folder(s) (log.csv, eval.jsonl)")
    p.add_argument("--label", action="append", default=None,
                   help="a run's name in the legend and table, once per run in order (default: the folder names)")
    p.add_argument("--out", type=Path, required=True, help="PNG file to write")
    p.add_argument("--title", default=None, help="figure title (default: the run folder's name)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..core.errors import SMFError
    from ..eval.curve import comparison_table, draw_comparison, draw_curve, read_run

    if args.out.suffix.lower() != ".png":
        raise SMFError(f"--out must be a .png file, got {args.out}")
    labels = args.label or [r.name for r in args.run]
    if len(labels) != len(args.run) or len(set(labels)) != len(labels):
        raise SMFError(f"--label: give one distinct name per run ({len(args.run)} runs, {len(labels)} names)")
    if len(args.run) > 1:
        runs = {name: read_run(run)[0] for name, run in zip(labels, args.run)}
        draw_comparison(runs, args.out, args.title or " vs ".join(labels))
        print(comparison_table(runs))
        print(f"wrote {args.out} ({len(runs)} runs)")
        return
    args.run = args.run[0]
    evals, log = read_run(args.run)
    draw_curve(evals, log, args.out, args.title or labels[0])
    last = evals[-1] if evals else None
    print(f"wrote {args.out} ({len(evals)} evaluations, {len(log['step'])} logged steps"
          + (f"; last at step {last['step']}" if last else "") + ")")
