"""`smf edit "TEXT" --motion FILE --mode MODE --out DIR`: regenerate part of a given motion from text."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub, name: str) -> None:
    from ..core.limits import EDIT_MODES, IMPOSE
    from .character import add_character_arguments
    from .options import add_sampling_arguments
    from .robot import add_robot_arguments

    p = sub.add_parser(name,
                       description="Keep part of a motion (its start, its end, both, one half of the body, or its "
                                   "root path) and generate the rest from the text; docs/editing.md.")
    p.add_argument("text", help="what the generated part should do")
    p.add_argument("--motion", required=True,
                   help="joints (T,J,3) or features (T,D) .npy, a .bvh (ours, or any with --joint-map), or "
                        "example:NAME")
    p.add_argument("--mode", required=True, choices=EDIT_MODES)
    p.add_argument("--keep-start", type=float, default=0.0, help="seconds kept at the start (prefix, inbetween)")
    p.add_argument("--keep-end", type=float, default=0.0, help="seconds kept at the end (suffix, inbetween)")
    p.add_argument("--seconds", type=float, default=None, help="output length (default: the source's)")
    p.add_argument("--path", type=Path, default=None,
                   help="trajectory mode: (T, 2) .npy of root X, Z positions in metres (default: the motion's own)")
    p.add_argument("--fps", type=float, default=None, help="frame rate of a joints .npy (default: the model's)")
    p.add_argument("--impose", default="x0", choices=IMPOSE,
                   help="keep the known part in the x0 prediction (default) or in the noisy sample")
    add_sampling_arguments(p)
    add_character_arguments(p, reads_motion=True)
    add_robot_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from .options import check_sampling

    check_sampling(args)  # before the heavy imports below: a bad flag is answered at once
    import numpy as np

    from ..core.edit_plan import check_edit_inputs, source_features
    from ..core.errors import SMFError
    from ..motion.files import check_values, load_motion, npy_header
    from ..core.output import parse_formats, write_results
    from .character import load_rig
    from .options import choose_engine, load_pipeline, output_meta, sampling_kwargs, user_warnings
    from .robot import robot_formats, write_robot_files

    choose_engine(args)
    formats = parse_formats(args.format)
    rig = load_rig(args, args.motion)
    robot = robot_formats(args)
    if not args.text.strip():
        raise SMFError("the prompt is empty")
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
        with open(args.path, "rb") as f:
            npy_header(f, args.path.stat().st_size, str(args.path))  # before its data is read
        try:
            path = np.load(args.path, allow_pickle=False).astype(np.float64)
        except Exception as e:  # noqa: BLE001 - numpy raises many types for broken files
            raise SMFError(f"{args.path}: not a readable .npy array ({e.__class__.__name__})") from None
        check_values(path, str(args.path))
    motion = load_motion(args.motion, joint_map=args.joint_map)
    check_edit_inputs(args.mode, args.keep_start, args.keep_end, args.seconds)
    kwargs = sampling_kwargs(args)
    pipe = load_pipeline(args)
    source = source_features(motion, pipe.skeleton, pipe.fps, args.fps)
    with user_warnings():
        result = pipe.edit(args.text, source, args.mode, keep_start=args.keep_start, keep_end=args.keep_end,
                           seconds=args.seconds, path=path, impose=args.impose, **kwargs)
    meta = {"edit": args.mode, "impose": args.impose, "keep_start": args.keep_start, "keep_end": args.keep_end,
            **output_meta(args, pipe, edit=True)}
    (stem,) = write_results([result], args.out, formats, meta, overwrite=args.overwrite, rig=rig)
    if robot:
        write_robot_files(args, result.joints, result.fps, result.contacts, stem, robot, meta)
