"""`smf convert INPUT OUTPUT [--to joints|features]`: between joints .npy, features .npy and .bvh."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import SMFError
from ..motion.files import load_motion, save_motion


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name, help="convert between joints .npy, features .npy and .bvh",
                       description="Convert a motion between joints .npy (T,J,3 metres), features .npy (T,263|251) "
                                   "and BVH. A .npy output holds the other kind than the input unless --to says.")
    p.add_argument("input", help="joints/features .npy, .bvh, or example:<name>")
    p.add_argument("output", type=Path)
    p.add_argument("--to", choices=["joints", "features"], default=None,
                   help="what a .npy output holds (default: features for a joints input, joints otherwise)")
    p.add_argument("--joint-map", default=None,
                   help="read a raw mocap .bvh input through a joint map: a built-in NAME (bandai-namco) or a JSON FILE")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    suffix = args.output.suffix.lower()
    if suffix not in (".npy", ".bvh"):
        raise SMFError(f"unsupported output extension '{args.output.suffix}'; use .npy or .bvh")
    motion = load_motion(args.input, joint_map=args.joint_map)
    if suffix == ".bvh":
        kind = "bvh"
    elif args.to is not None:
        kind = args.to
    else:
        from_joints = not str(args.input).lower().endswith(".bvh") and motion.features is None
        kind = "features" if from_joints else "joints"
    save_motion(motion, args.output, kind)
    print(f"wrote {args.output} ({kind}, {len(motion.joints)} frames)")
