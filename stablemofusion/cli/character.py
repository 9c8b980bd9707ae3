"""The flags that put a motion on the user's character: ``--rig RIG.bvh --joint-map MAP`` (the motion retargeted
onto that skeleton, written as ``NAME_rig.bvh`` beside the other outputs, or as the output of `smf convert`).
``--joint-map`` names how the user's skeleton matches ours: it maps ``--rig`` and, for the commands that read a
motion, a raw mocap ``.bvh`` input of that skeleton."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core.errors import SMFError


def add_character_arguments(p: argparse.ArgumentParser, *, reads_motion: bool) -> None:
    """--rig and --joint-map."""
    p.add_argument("--rig", type=Path, default=None,
                   help="also write the motion on this BVH skeleton (its joints, order, names, offsets and channels; "
                        "needs --joint-map)")
    p.add_argument("--joint-map", default=None,
                   help="how your skeleton's joints match ours: a built-in NAME (bandai-namco, mixamo, humanml3d) or a "
                        "JSON FILE as `smf prepare bvh --joint-map` reads; maps --rig"
                        + (" and reads a raw mocap .bvh input" if reads_motion else ""))


def load_rig(args: argparse.Namespace, motion_input: str | None = None):
    """The :class:`~stablemofusion.core.output.Rig` of --rig/--joint-map (None without --rig), checked before any
    generation. ``motion_input``: the command's input motion, which may use --joint-map without --rig."""
    from ..motion.bvh import read_bvh
    from ..motion.retarget import JointMap
    from ..core.output import Rig

    if args.rig is None:
        if args.joint_map is not None and not str(motion_input or "").lower().endswith(".bvh"):
            raise SMFError("--joint-map maps --rig RIG.bvh" + (" or a raw mocap .bvh input" if motion_input else "")
                           + "; give --rig")
        return None
    if args.joint_map is None:
        raise SMFError("--rig needs --joint-map (a built-in name such as mixamo or bandai-namco, or a JSON file)")
    if args.rig.suffix.lower() != ".bvh":
        raise SMFError(f"--rig must be a .bvh file, got {args.rig}")
    if not args.rig.is_file():
        raise SMFError(f"no such file: {args.rig}")
    return Rig(read_bvh(args.rig), JointMap.named(args.joint_map))
