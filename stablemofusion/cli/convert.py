"""`smf convert INPUT OUTPUT [--to joints|features] [--rig RIG.bvh --joint-map MAP]`: between joints .npy,
features .npy, .bvh and .glb, or onto the user's skeleton."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core.errors import SMFError
from .character import add_character_arguments, load_rig
from .flags import add_overwrite_flag, check_new_output
from .robot import add_robot_arguments

OUTPUTS = (".npy", ".bvh", ".glb")


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Convert a motion from joints .npy (T,J,3 metres), features .npy (T,263|251) or BVH to "
                                   "any of those or glTF 2.0 binary (.glb, output only: a skinned character with "
                                   "one animation). A .npy "
                                   "output holds the other kind than the input unless --to says. With --rig and "
                                   "--joint-map the .bvh output is the motion on that rig's skeleton.")
    p.add_argument("input", help="joints/features .npy, .bvh (ours, or any with --joint-map), or example:<name>")
    p.add_argument("output", type=Path, help="output file: .npy, .bvh or .glb; with --robot .npz, .csv, .xml, .mp4 "
                                                  "or .gif (the robot's trajectory)")
    p.add_argument("--to", choices=["joints", "features"], default=None,
                   help="what a .npy output holds (default: features for a joints input, joints otherwise)")
    add_overwrite_flag(p)
    add_character_arguments(p, reads_motion=True)
    add_robot_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..core.io import write_bytes
    from ..motion.files import load_motion, rigid_pose, save_motion
    from ..core.output import glb_bytes, rig_bvh_text
    from ..core.result import MotionResult

    suffix = args.output.suffix.lower()
    if args.robot is not None:
        return convert_to_robot(args, suffix)
    if suffix not in OUTPUTS:
        raise SMFError(f"unsupported output extension '{args.output.suffix}'; use {', '.join(OUTPUTS)}")
    rig = load_rig(args, args.input)
    if rig is not None and suffix != ".bvh":
        raise SMFError(f"--rig writes the rig's BVH: give an output ending in .bvh, not '{args.output.suffix}'")
    check_new_output(args.output, args.overwrite)
    motion = load_motion(args.input, joint_map=args.joint_map)
    if rig is not None or suffix == ".glb":
        result = MotionResult(str(args.input), motion.features, motion.joints, motion.fps, None,
                              rigid_pose(motion.joints, motion.skeleton))
        data = rig_bvh_text(result, rig).encode("utf-8") if rig is not None else glb_bytes(result)
        write_bytes(args.output, data)
        where = f"on {args.rig.name}" if rig is not None else "glb"
        print(f"wrote {args.output} ({where}, {len(motion.joints)} frames)")
        return
    if suffix == ".bvh":
        kind = "bvh"
    elif args.to is not None:
        kind = args.to
    else:
        from_joints = not str(args.input).lower().endswith(".bvh") and motion.features is None
        kind = "features" if from_joints else "joints"
    save_motion(motion, args.output, kind)
    print(f"wrote {args.output} ({kind}, {len(motion.joints)} frames)")


def convert_to_robot(args: argparse.Namespace, suffix: str) -> None:
    """A motion file retargeted to --robot, written as the output's format (.npz, .csv, .xml, .mp4, .gif)."""
    from ..motion.files import load_motion
    from ..robots.files import ROBOT_FORMATS, write_robot
    from ..robots.model import load_robot
    from ..robots.retarget import retarget

    fmt = suffix.lstrip(".")
    if fmt not in ROBOT_FORMATS:
        raise SMFError(f"with --robot the output is the robot's trajectory: end it in "
                       f"{', '.join('.' + f for f in ROBOT_FORMATS)}, not '{args.output.suffix}'")
    if args.robot_format is not None or args.rig is not None:
        raise SMFError("with --robot, convert writes one file, in its output's format: --robot-format and --rig do "
                       "not apply")
    check_new_output(args.output, args.overwrite)
    robot = load_robot(args.robot, None if args.robot_map is None else str(args.robot_map))
    motion = load_motion(args.input, joint_map=args.joint_map)
    if motion.joints.shape[1] != 22:
        raise SMFError(f"--robot retargets our 22-joint skeleton; {args.input} has {motion.joints.shape[1]} joints")
    trajectory = retarget(robot, motion.joints, motion.fps)
    written = write_robot(trajectory, robot, args.output.with_suffix(""), [fmt])[0]
    written.replace(args.output)
    print(f"wrote {args.output} ({trajectory.robot}, {len(trajectory.qpos)} frames at {trajectory.fps:g} Hz)")
