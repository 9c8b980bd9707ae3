"""A corpus in the HumanML3D layout from a user's own BVH files and a joint map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..core.errors import SMFError
from ..core.io import save_npy, write_text
from ..motion.features import features_from_joints, joints_from_features
from ..motion.retarget import JointMap, retarget_bvh
from .layout import CaptionLine, format_text_line, mean_std, parse_text_line


def _caption_lines(path: Path) -> str:
    """Captions beside a BVH (``name.txt``): official ``caption#tokens#start#end`` lines or plain sentences."""
    if not path.is_file():
        return ""
    out = []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        if "#" in line:
            out.append(format_text_line(parse_text_line(line, f"{path}:{n}")))
        else:
            words = [w.strip(".,;:!?").lower() for w in line.split()]
            out.append(format_text_line(CaptionLine(line, [f"{w}/X" for w in words if w], 0.0, 0.0)))
    return "".join(s + "\n" for s in out)


def build_bvh_corpus(src: Path, joint_map: Path, out: Path, unit: str = "auto") -> int:
    """Retarget every ``*.bvh`` under ``src`` and write the layout at ``out``; returns the motion count."""
    src, out = Path(src), Path(out)
    if not src.is_dir():
        raise SMFError(f"no such folder: {src}")
    files = sorted(src.rglob("*.bvh"))
    if not files:
        raise SMFError(f"no .bvh files under {src}")
    jmap = JointMap.load(joint_map)
    ids, feats_all = [], []
    for f in tqdm(files, desc="bvh", unit="file"):
        joints = retarget_bvh(f, jmap, unit=unit)
        if len(joints) < 2:
            raise SMFError(f"{f}: needs at least 2 frames at 20 fps")
        feats = features_from_joints(joints)
        mid = f.relative_to(src).with_suffix("").as_posix().replace("/", "__")
        save_npy(out / "new_joint_vecs" / f"{mid}.npy", feats.astype(np.float32))
        save_npy(out / "new_joints" / f"{mid}.npy", joints_from_features(feats).astype(np.float32))
        write_text(out / "texts" / f"{mid}.txt", _caption_lines(f.with_suffix(".txt")))
        ids.append(mid)
        feats_all.append(feats)
    mean, std = mean_std(feats_all, "humanml3d")
    save_npy(out / "Mean.npy", mean.astype(np.float32))
    save_npy(out / "Std.npy", std.astype(np.float32))
    listing = "".join(i + "\n" for i in ids)
    for name in ("all", "train"):
        write_text(out / f"{name}.txt", listing)
    return len(ids)
