"""`smf edit "TEXT" --motion FILE --mode MODE --out DIR`: regenerate part of a given motion from text."""

from __future__ import annotations

import argparse
from pathlib import Path

from .generate import FORMATS


def add_parser(sub, name: str) -> None:
    from ..diffusion.samplers import DEFAULT_SAMPLER
    from ..edit import EDIT_MODES, IMPOSE

    p = sub.add_parser(name, help="edit a motion with text: keep part of it, generate the rest",
                       description="Keep part of a motion (its start, its end, both, one half of the body, or its "
                                   "root path) and generate the rest from the text; docs/editing.md.")
    p.add_argument("text", help="what the generated part should do")
    p.add_argument("--motion", required=True,
                   help="joints (T,J,3) or features (T,D) .npy, a .bvh of our skeleton, or example:NAME")
    p.add_argument("--mode", required=True, choices=EDIT_MODES)
    p.add_argument("--keep-start", type=float, default=0.0, help="seconds kept at the start (prefix, inbetween)")
    p.add_argument("--keep-end", type=float, default=0.0, help="seconds kept at the end (suffix, inbetween)")
    p.add_argument("--seconds", type=float, default=None, help="output length (default: the source's)")
    p.add_argument("--path", type=Path, default=None,
                   help="trajectory mode: (T, 2) .npy of root X, Z positions in metres (default: the motion's own)")
    p.add_argument("--fps", type=float, default=None, help="frame rate of a joints .npy (default: the model's)")
    p.add_argument("--impose", default="x0", choices=IMPOSE,
                   help="keep the known part in the x0 prediction (default) or in the noisy sample")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--format", default="npy,mp4,bvh", help=f"comma list of {','.join(FORMATS)} (default npy,mp4,bvh)")
    p.add_argument("--guidance", type=float, default=2.5)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--sampler", default=DEFAULT_SAMPLER)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--checkpoint", type=Path, default=None, help="checkpoint or run folder (default: shipped model)")
    p.add_argument("--device", default=None)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import numpy as np

    from ..edit import source_features
    from ..errors import SMFError
    from ..motion.files import load_motion
    from ..pipeline import MotionPipeline
    from .generate import parse_formats, write_results

    formats = parse_formats(args.format)
    if not args.text.strip():
        raise SMFError("the prompt is empty")
    for flag in ("keep_start", "keep_end"):
        if not (np.isfinite(getattr(args, flag)) and getattr(args, flag) >= 0):
            raise SMFError(f"--{flag.replace('_', '-')} must be a finite number of seconds >= 0")
    for flag in ("fps", "seconds"):
        value = getattr(args, flag)
        if value is not None and not (np.isfinite(value) and value > 0):
            raise SMFError(f"--{flag} must be a finite positive number, got {value}")
    path = None
    if args.path is not None:
        if args.mode != "trajectory":
            raise SMFError("--path is for --mode trajectory")
        if not args.path.is_file():
            raise SMFError(f"no such file: {args.path}")
        try:
            path = np.load(args.path, allow_pickle=False).astype(np.float64)
        except Exception as e:  # noqa: BLE001 - numpy raises many types for broken files
            raise SMFError(f"{args.path}: not a readable .npy array ({e.__class__.__name__})") from None
    pipe = MotionPipeline.from_pretrained(args.checkpoint, device=args.device)
    source = source_features(load_motion(args.motion), pipe.skeleton, pipe.fps, args.fps)
    result = pipe.edit(args.text, source, args.mode, keep_start=args.keep_start, keep_end=args.keep_end,
                       seconds=args.seconds, path=path, guidance_scale=args.guidance, steps=args.steps,
                       sampler=args.sampler, seed=args.seed, impose=args.impose)
    write_results([result], args.out, formats, pipe.skeleton,
                  {"edit": args.mode, "impose": args.impose, "keep_start": args.keep_start, "keep_end": args.keep_end,
                   "sampler": args.sampler, "steps": args.steps, "guidance": args.guidance})
