"""The robot flags `smf generate` and `smf convert` share: --robot, --robot-map, --robot-format."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core.errors import SMFError

DEFAULT_ROBOT_FORMATS = "npz,csv"


def add_robot_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--robot", default=None, metavar="g1|h1|ROBOT.xml",
                   help="also retarget each motion to this humanoid robot (the shipped Unitree G1 or H1, or an MJCF "
                        "file with a free joint) and write its qpos trajectory at 50 Hz (docs/robots.md; needs "
                        "pip install 'stablemofusion[robot]')")
    p.add_argument("--robot-map", type=Path, default=None, metavar="MAP.json",
                   help="which robot site each of our joints drives (default: the robot's BODY_25 keypoint sites)")
    p.add_argument("--robot-format", default=None,
                   help=f"robot files to write, comma separated from npz, csv, xml (MuJoCo keyframes), mp4, gif "
                        f"(default with --robot: {DEFAULT_ROBOT_FORMATS})")


def robot_formats(args: argparse.Namespace) -> list[str]:
    """The checked --robot-format list (empty without --robot); the robot itself is loaded now, so that a bad robot,
    map or missing MuJoCo is answered before any generation."""
    if args.robot is None:  # MuJoCo is imported only when a robot is asked for
        if args.robot_map is not None or args.robot_format is not None:
            raise SMFError("--robot-map and --robot-format go with --robot")
        return []
    from ..robots.files import ROBOT_FORMATS
    from ..robots.model import load_robot

    formats = [f.strip().lower() for f in (args.robot_format or DEFAULT_ROBOT_FORMATS).split(",") if f.strip()]
    bad = [f for f in formats if f not in ROBOT_FORMATS]
    if bad or not formats:
        raise SMFError(f"unknown robot format {', '.join(bad) or '(none)'}; choose from {', '.join(ROBOT_FORMATS)}")
    if {"mp4", "gif"} & set(formats):
        from ..render.encoders import check_encoder

        for f in {"mp4", "gif"} & set(formats):
            check_encoder(f)
    load_robot(args.robot, None if args.robot_map is None else str(args.robot_map))
    return formats


def write_robot_files(args: argparse.Namespace, joints, fps: float, contacts, stem: Path, formats: list[str],
                      meta: dict | None = None) -> list[Path]:
    """Retarget one motion and write its robot files beside ``stem``; prints one line."""
    from ..robots.files import write_robot
    from ..robots.model import load_robot
    from ..robots.retarget import retarget

    robot = load_robot(args.robot, None if args.robot_map is None else str(args.robot_map))
    motion = retarget(robot, joints, fps, contacts)
    paths = write_robot(motion, robot, stem, formats, meta)
    print(f"wrote {stem}.{motion.robot}.{{{','.join(formats)}}} ({len(motion.qpos)} frames at {motion.fps:g} Hz)")
    return paths
