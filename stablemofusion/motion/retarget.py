"""Retarget any BVH skeleton onto a fixed joint layout (HumanML3D's 22 joints by default).

A joint map is JSON: ``{"joints": {"<our joint>": "<source joint>" | ["<a>", "<b>"], ...}}`` where a pair
means the midpoint of two source joints (for a joint the source lacks, e.g. a third spine joint). Every
one of our joints must be mapped.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import SMFError
from .bvh import BVH, forward_kinematics, read_bvh
from .files import resample
from .skeleton import Skeleton, get_skeleton


@dataclass(frozen=True)
class JointMap:
    """For each of our joints (in skeleton order) the source joint names whose mean gives its position."""

    skeleton: str
    sources: tuple[tuple[str, ...], ...]

    @staticmethod
    def from_dict(data: dict, skeleton: str | Skeleton = "humanml3d", where: str = "joint map") -> "JointMap":
        sk = get_skeleton(skeleton)
        joints = data.get("joints") if isinstance(data, dict) else None
        if not isinstance(joints, dict):
            raise SMFError(f"{where}: expected an object with a 'joints' mapping")
        unknown = sorted(set(joints) - set(sk.joint_names))
        if unknown:
            raise SMFError(f"{where}: unknown {sk.name} joint(s) {unknown}; known: {', '.join(sk.joint_names)}")
        missing = [n for n in sk.joint_names if n not in joints]
        if missing:
            raise SMFError(f"{where}: no source for {sk.name} joint(s) {missing}")
        sources = []
        for name in sk.joint_names:
            src = joints[name]
            src = (src,) if isinstance(src, str) else tuple(src) if isinstance(src, list) else None
            if not src or len(src) > 2 or not all(isinstance(s, str) for s in src):
                raise SMFError(f"{where}: '{name}' must map to a joint name or a list of two names")
            sources.append(src)
        return JointMap(sk.name, tuple(sources))

    @staticmethod
    def load(path: str | Path, skeleton: str | Skeleton = "humanml3d") -> "JointMap":
        path = Path(path)
        if not path.is_file():
            raise SMFError(f"no such joint map: {path}")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise SMFError(f"{path}: not valid JSON ({e})") from None
        return JointMap.from_dict(data, skeleton, str(path))

    @staticmethod
    def builtin(name: str) -> "JointMap":
        """A joint map shipped with the package, e.g. 'bandai-namco'."""
        res = resources.files("stablemofusion") / "assets" / "joint_maps" / f"{name}.json"
        if not res.is_file():
            raise SMFError(f"no built-in joint map named {name!r}")
        return JointMap.from_dict(json.loads(res.read_text(encoding="utf-8")), "humanml3d", name)

    @staticmethod
    def named(name_or_path: str | Path) -> "JointMap":
        """A JSON file's joint map if ``name_or_path`` is a file (or ends in .json), else the built-in of that name."""
        path = Path(name_or_path)
        if path.is_file() or path.suffix.lower() == ".json":
            return JointMap.load(path)
        return JointMap.builtin(str(name_or_path))

    def apply(self, positions: np.ndarray, names: list[str], where: str = "BVH") -> np.ndarray:
        """Source world positions (T, S, 3) with joint ``names`` -> our joints (T, J, 3)."""
        index = {n: i for i, n in enumerate(names)}
        absent = sorted({s for src in self.sources for s in src if s not in index})
        if absent:
            raise SMFError(f"{where}: joint map names source joint(s) {absent} that the file lacks")
        return np.stack([positions[:, [index[s] for s in src]].mean(axis=1) for src in self.sources], axis=1)


def retarget_bvh(bvh: BVH | str | Path, joint_map: JointMap, *, fps: float | None = None,
                 unit: str = "auto") -> np.ndarray:
    """BVH (object or path) -> our joints (T, J, 3) in metres, Y up, resampled to ``fps`` (skeleton's by default)."""
    where = str(bvh) if not isinstance(bvh, BVH) else "BVH"
    if not isinstance(bvh, BVH):
        bvh = read_bvh(bvh, unit=unit)
    sk = get_skeleton(joint_map.skeleton)
    joints = joint_map.apply(forward_kinematics(bvh), list(bvh.names), where)
    return resample(joints, bvh.fps, fps or sk.fps)
