"""The motion on a character, for the commands that write motions: ``--format glb`` (glTF 2.0 binary) and
``--rig RIG.bvh --joint-map MAP`` (the motion retargeted onto the user's skeleton, as a BVH of that rig)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..errors import SMFError


def add_character_arguments(p: argparse.ArgumentParser) -> None:
    """--rig and --joint-map."""
    p.add_argument("--rig", type=Path, default=None,
                   help="also write the motion retargeted onto this BVH skeleton (its joints, order, offsets and "
                        "channels; needs --joint-map)")
    p.add_argument("--joint-map", default=None,
                   help="how the rig's joints match ours: a built-in name (bandai-namco, mixamo, humanml3d) or a "
                        "JSON file as `smf prepare bvh --joint-map` reads")


def load_rig(args: argparse.Namespace):
    """(rig BVH, JointMap) from --rig/--joint-map, or None without --rig; checked before any generation."""
    from ..motion.bvh import read_bvh
    from ..motion.retarget import resolve_joint_map

    if args.rig is None:
        if args.joint_map is not None:
            raise SMFError("--joint-map needs --rig RIG.bvh")
        return None
    if args.joint_map is None:
        raise SMFError("--rig needs --joint-map (a built-in name such as mixamo or bandai-namco, or a JSON file)")
    if args.rig.suffix.lower() != ".bvh":
        raise SMFError(f"--rig must be a .bvh file, got {args.rig}")
    return read_bvh(args.rig), resolve_joint_map(args.joint_map)


def write_rig_bvh(joints: np.ndarray, rig, path: Path, fps: float) -> None:
    """Our joints (T, 22, 3) retargeted onto ``rig`` (from :func:`load_rig`), written as a BVH to ``path``."""
    from ..motion.retarget import save_rig_bvh

    if joints.shape[1:] != (22, 3):
        raise SMFError(f"retargeting onto a rig needs a 22-joint (HumanML3D) motion, got {joints.shape[1]} joints")
    bvh, jmap = rig
    save_rig_bvh(joints, bvh, jmap, path, fps)


def write_character_files(results, out: Path, formats: list[str], rig, stem) -> None:
    """For each pipeline result: ``<stem>.glb`` when 'glb' is in ``formats``, ``<stem>_rig.bvh`` with a rig;
    ``stem(prompt, i)`` names the files as the other outputs are named."""
    from ..motion.files import rigid_pose
    from ..motion.gltf import save_glb

    for i, r in enumerate(results):
        base = out / stem(r.prompt, i)
        if "glb" in formats:
            save_glb(r.motion if r.motion is not None else rigid_pose(r.joints), base.with_suffix(".glb"), r.fps)
        if rig is not None:
            write_rig_bvh(r.joints, rig, base.with_name(base.name + "_rig.bvh"), r.fps)
