"""`smf prepare bandai|bvh ...`: build a corpus in the official HumanML3D layout."""

from __future__ import annotations

import argparse
import os
from pathlib import Path


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Build a corpus in the official HumanML3D layout (new_joints, new_joint_vecs, "
                                   "texts, Mean/Std, splits).")
    kinds = p.add_subparsers(dest="kind", metavar="SOURCE", required=True)
    b = kinds.add_parser("bandai", help="the Bandai-Namco motion datasets 1 and 2 (CC BY-NC 4.0)")
    b.add_argument("--source", type=Path, required=True,
                   help="bandai-namco-motion.tar.xz, or a folder where it is unpacked")
    b.add_argument("--out", type=Path, required=True, help="corpus folder to create or complete")
    b.add_argument("--cache", type=Path, default=None, help="where to unpack the archive (default OUT/.source)")
    b.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    b.add_argument("--limit", type=int, default=None, help="only this many clips, spread over the labels")
    b.add_argument("--captions", type=int, default=16, help="captions per motion (default 16)")
    b.add_argument("--first-frame", default="official", choices=("official", "consistent"),
                   help="frame 0's body frame: HumanML3D's (official, default) or the one every other frame uses "
                        "(consistent: no yaw jump at frame 0; docs/rigid.md)")
    b.set_defaults(func=run_bandai)
    u = kinds.add_parser("bvh", help="your own BVH files, retargeted with a joint map")
    u.add_argument("dir", type=Path, help="folder with .bvh files (searched recursively); optional <name>.txt "
                                          "captions beside each file, one per line")
    u.add_argument("--joint-map", type=Path, required=True,
                   help='JSON {"joints": {"pelvis": "Hips", "spine2": ["Spine", "Chest"], ...}}')
    u.add_argument("--out", type=Path, required=True)
    u.add_argument("--unit", default="auto", choices=["auto", "m", "cm", "mm", "inch"])
    u.set_defaults(func=run_bvh)


def run_bandai(args: argparse.Namespace) -> None:
    from ..data.corpus_bandai import build_corpus, format_stats
    from ..core.errors import SMFError

    if args.limit is not None and args.limit < 1:
        raise SMFError("--limit must be at least 1")
    stats = build_corpus(args.source, args.out, cache=args.cache, workers=args.workers, limit=args.limit,
                         n_captions=args.captions, first_frame=args.first_frame)
    print(format_stats(stats))
    print(f"wrote {args.out} (figures in {args.out / 'stats.json'})")


def run_bvh(args: argparse.Namespace) -> None:
    from ..data.corpus_bvh import build_bvh_corpus

    n = build_bvh_corpus(args.dir, args.joint_map, args.out, unit=args.unit)
    print(f"wrote {n} motions to {args.out}")
