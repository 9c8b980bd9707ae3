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

from ..core.errors import SMFError
from .bvh import BVH, UNIT_SCALES, forward_kinematics, read_bvh
from .resample import resample
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
            raise SMFError(f"no joint map file or built-in map named {name!r}; built-in: {', '.join(builtin_joint_maps())}")
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


# --- onto a user's skeleton (the reverse direction: our motion -> their BVH rig); math in .rig -------------

def builtin_joint_maps() -> list[str]:
    """Names of the joint maps shipped with the package (assets/joint_maps/*.json)."""
    folder = resources.files("stablemofusion") / "assets" / "joint_maps"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".json"))


def rig_from_bvh(bvh: BVH) -> "Rig":
    """The rest skeleton of a BVH file as a :class:`~stablemofusion.motion.rig.Rig` (metres)."""
    from .rig import Rig

    return Rig(list(bvh.names), bvh.parents, bvh.offsets)


def _carrier(bvh: BVH, pelvis: int) -> int:
    """The joint whose position channels carry the path: the pelvis's own where it has them (Bandai-Namco's
    Hips), else the root's."""
    for j in (pelvis, 0):
        if sum(c.endswith("position") for c in bvh.channels[j]) == 3:
            return j
    raise SMFError(f"rig: neither {bvh.names[pelvis]!r} nor the root {bvh.names[0]!r} has 3 position channels")


def retarget_onto_bvh(joints: np.ndarray, rig: BVH, joint_map: JointMap):
    """Our joints (T, 22, 3) metres -> :class:`~stablemofusion.motion.rig.RigMotion` on ``rig``'s skeleton."""
    from .rig import retarget, targets_from_sources

    if joint_map.skeleton != "humanml3d":
        raise SMFError(f"retargeting onto a rig needs a HumanML3D joint map, got {joint_map.skeleton}")
    targets = targets_from_sources(list(rig.names), list(joint_map.sources))
    pelvis = int(np.flatnonzero(targets == 0)[0]) if (targets == 0).any() else 0
    return retarget(joints, rig_from_bvh(rig), targets, carrier=_carrier(rig, pelvis))


def rig_bvh_text(rig: BVH, motion, fps: float, precision: int = 6) -> str:
    """The BVH text of a :class:`~stablemofusion.motion.rig.RigMotion` on ``rig``: the template's joints, order,
    names, offsets, end sites, channel layout and unit; rotations in each joint's own channel order."""
    from .rotation import matrix_to_euler

    unit = UNIT_SCALES[rig.unit]
    T, R = motion.rotations.shape[:2]
    columns = []
    for j, chans in enumerate(rig.channels):
        rot = [c[0] for c in chans if c.endswith("rotation")]
        if len(rot) == 3:
            euler = matrix_to_euler(motion.rotations[:, j], "".join(rot))
        elif not np.allclose(motion.rotations[:, j], np.eye(3), atol=1e-6):
            raise SMFError(f"rig: joint {rig.names[j]!r} must turn but has {len(rot)} rotation channel(s), not 3")
        k = 0
        for c in chans:
            if c.endswith("position"):
                columns.append(motion.translations[:, j, "XYZ".index(c[0])] / unit)
            else:
                columns.append(euler[:, k] if len(rot) == 3 else np.zeros(T))
                k += 1
    data = np.round(np.stack(columns, -1) if columns else np.zeros((T, 0)), precision) + 0.0

    def num(v) -> str:
        return " ".join(f"{x + 0.0:.{precision}f}" for x in np.round(np.asarray(v) / unit, precision))

    children: list[list[int]] = [[] for _ in range(R)]
    for j in range(1, R):
        children[rig.parents[j]].append(j)
    out = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        ind = "\t" * depth
        out.extend([f"{ind}{'ROOT' if j == 0 else 'JOINT'} {rig.names[j]}", f"{ind}{{",
                    f"{ind}\tOFFSET {num(rig.offsets[j])}", f"{ind}\tCHANNELS {len(rig.channels[j])} "
                    + " ".join(rig.channels[j])])
        for c in children[j]:
            emit(c, depth + 1)
        if j in rig.end_sites:
            out.extend([f"{ind}\tEnd Site", f"{ind}\t{{", f"{ind}\t\tOFFSET {num(rig.end_sites[j])}", f"{ind}\t}}"])
        out.append(f"{ind}}}")

    emit(0, 0)
    row = " ".join([f"%.{precision}f"] * data.shape[1])
    out += ["MOTION", f"Frames: {T}", f"Frame Time: {1.0 / fps:.9g}"]
    out += [row % tuple(r) for r in data.tolist()]
    return "\n".join(out) + "\n"
