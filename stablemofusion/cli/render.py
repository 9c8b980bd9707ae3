"""`smf render INPUT --out FILE.mp4|.gif|.png [--frame N] [--title TEXT]`."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core.errors import SMFError
from .flags import add_overwrite_flag, check_new_output


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Render a motion (joints .npy, features .npy or our .bvh) as a video or PNG still.")
    p.add_argument("input", help="motion file: joints (T,J,3) .npy, features (T,D) .npy, .bvh, or example:<name>")
    p.add_argument("--out", type=Path, required=True, help="output .mp4, .gif, or .png (with --frame)")
    p.add_argument("--title", default=None, help="text shown above the figure")
    p.add_argument("--frame", type=int, default=None, help="render only this frame as a PNG still")
    p.add_argument("--size", type=int, default=480, help="image size in pixels (default 480)")
    add_overwrite_flag(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..motion.files import load_motion
    from ..render import render_frame, render_video

    suffix = args.out.suffix.lower()
    if args.frame is None and suffix == ".png":
        raise SMFError("a .png output needs --frame N")
    if args.frame is not None and suffix != ".png":
        raise SMFError(f"--frame writes a still image; use an output ending in .png, not '{args.out.suffix}'")
    if suffix not in (".mp4", ".gif", ".png"):
        raise SMFError(f"unsupported output format '{args.out.suffix}'; use .mp4, .gif or .png")
    check_new_output(args.out, args.overwrite)
    motion = load_motion(args.input)
    title = args.title if args.title is not None else Path(args.input).stem.replace("example:", "")
    if args.frame is not None:
        render_frame(motion.joints, args.frame, args.out, skeleton=motion.skeleton, title=title, size=args.size)
    else:
        render_video(motion.joints, args.out, skeleton=motion.skeleton, fps=motion.fps, title=title, size=args.size)
    print(f"wrote {args.out}")
