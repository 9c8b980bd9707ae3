"""A user's clips for an adapter: a folder of BVH files on any rig, read through a joint map, with a caption each.

Captions come from one of three places (:func:`read_clips` says which it used):
- ``captions.csv`` in the folder, or a CSV given explicitly: a header ``file,caption`` and one row per clip
  (a file may have several rows: several captions of one clip);
- one caption for the whole folder (``caption``);
- the file names (``from_names``): ``kick_high_02.bvh`` -> "a person kick high" is rarely good English, so this
  is a last resort for folders named by action.
Every clip is checked: readable, the joints the map names present, bones of a body, at least the model's
shortest length; a clip without a caption, or a caption naming no clip, is an error.
"""

from __future__ import annotations

import csv
import io
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import SMFError

CAPTIONS_FILE = "captions.csv"
MAX_CLIPS = 5000
MAX_SKIPPED = 0.5  # share of a folder's clips that may be unusable (skipped, said); past it the run stops


class ClipSkippedWarning(UserWarning):
    """A clip of the folder cannot be used (too short, unreadable, not a body's joints) and is left out."""
MAX_CSV_BYTES = 4 * 2**20
MAX_CAPTION_CHARS = 300


@dataclass(frozen=True)
class Clip:
    """One clip: its file (relative to the folder), captions, and features (T, D) in dataset units at the
    skeleton's frame rate."""

    file: str
    captions: tuple[str, ...]
    features: np.ndarray

    @property
    def frames(self) -> int:
        return int(self.features.shape[0])


def caption_from_name(name: str) -> str:
    """``run_fast_02`` -> "a person run fast": the words of a file name without digits."""
    words = [w for w in re.split(r"[^A-Za-z]+", Path(name).stem) if w]
    if not words:
        raise SMFError(f"{name}: its file name has no words to make a caption from")
    return "a person " + " ".join(w.lower() for w in words)


def read_caption_csv(path: Path) -> dict[str, list[str]]:
    """file -> captions from a ``file,caption`` CSV (header required)."""
    if not path.is_file():
        raise SMFError(f"no such captions file: {path}")
    if path.stat().st_size > MAX_CSV_BYTES:
        raise SMFError(f"{path}: larger than {MAX_CSV_BYTES // 2**20} MB; a captions file is one line per clip")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        raise SMFError(f"{path}: not UTF-8 text (byte {e.start}); save the captions file as UTF-8") from None
    try:
        rows = list(csv.reader(io.StringIO(text)))
    except csv.Error as e:  # a field past the csv module's limit (131,072 characters), a NUL byte
        raise SMFError(f"{path}: not a readable CSV file ({e}); captions are at most {MAX_CAPTION_CHARS} "
                       "characters") from None
    if not rows or [c.strip().lower() for c in rows[0][:2]] != ["file", "caption"]:
        raise SMFError(f"{path}: the first line must be the header 'file,caption'")
    out: dict[str, list[str]] = {}
    for n, row in enumerate(rows[1:], 2):
        if not row or not "".join(row).strip():
            continue
        if len(row) != 2:
            raise SMFError(f"{path}:{n}: expected 2 columns (file,caption), got {len(row)} (quote captions with commas)")
        name, caption = row[0].strip(), " ".join(row[1].split())
        if not caption:
            raise SMFError(f"{path}:{n}: {name} has an empty caption")
        if len(caption) > MAX_CAPTION_CHARS:
            raise SMFError(f"{path}:{n}: caption longer than {MAX_CAPTION_CHARS} characters")
        out.setdefault(name, []).append(caption)
    if not out:
        raise SMFError(f"{path}: no captions")
    return out


def read_clips(folder: str | Path, joint_map: str | Path = "bandai-namco", *, captions: str | Path | None = None,
               caption: str | None = None, from_names: bool = False, min_frames: int = 40, unit: str = "auto",
               skeleton: str = "humanml3d", progress: bool = False) -> tuple[list[Clip], str]:
    """Every ``*.bvh`` under ``folder`` (recursively), retargeted with ``joint_map`` (a built-in name or a
    JSON file) to ``skeleton`` features, with their captions; returns (clips, where the captions came from)."""
    from tqdm import tqdm

    from ..motion.retarget import JointMap
    from ..motion.skeleton import get_skeleton

    folder = Path(folder)
    if not folder.is_dir():
        raise SMFError(f"no such folder: {folder}")
    files = sorted(folder.rglob("*.bvh"), key=lambda p: p.relative_to(folder).as_posix())
    if not files:
        raise SMFError(f"no .bvh files under {folder}")
    if len(files) > MAX_CLIPS:
        raise SMFError(f"{folder}: {len(files)} clips; at most {MAX_CLIPS} per adapter")
    given = sum([captions is not None, caption is not None, from_names])
    if given > 1:
        raise SMFError("give one source of captions: --captions FILE.csv, --caption TEXT or --captions-from-names")
    if given == 0:
        if not (folder / CAPTIONS_FILE).is_file():
            raise SMFError(f"no captions for {folder}: put a {CAPTIONS_FILE} (file,caption) in it, or give --captions "
                           "FILE.csv, --caption TEXT (one for all clips) or --captions-from-names")
        captions = folder / CAPTIONS_FILE
    names = [f.relative_to(folder).as_posix() for f in files]
    if caption is not None:
        caption = " ".join(caption.split())
        if not caption or len(caption) > MAX_CAPTION_CHARS:
            raise SMFError(f"--caption must be 1 to {MAX_CAPTION_CHARS} characters")
        table, source = {n: [caption] for n in names}, "one caption for every clip (--caption)"
    elif from_names:
        table, source = {n: [caption_from_name(n)] for n in names}, "the file names"
    else:
        table, source = read_caption_csv(Path(captions)), str(captions)
        unknown = sorted(set(table) - set(names))
        if unknown:
            raise SMFError(f"{captions}: names {len(unknown)} file(s) that are not .bvh files under {folder} "
                           f"(e.g. {unknown[0]}); write paths relative to the folder")
        missing = [n for n in names if n not in table]
        if missing:
            raise SMFError(f"{folder / missing[0]}: no caption in {captions} ({len(missing)} clip(s) lack one)")
    jmap = JointMap.named(joint_map)
    sk = get_skeleton(skeleton)
    clips, skipped = [], []
    for f, name in zip(tqdm(files, desc="clips", unit="file", disable=None if progress else True), names):
        try:
            clips.append(Clip(name, tuple(table[name]), _clip_features(f, jmap, sk, unit, min_frames)))
        except SMFError as e:  # this clip is unusable: skipped, said, unless too few are left
            skipped.append(str(e))
    if skipped and (not clips or len(skipped) > len(files) * MAX_SKIPPED):
        raise SMFError(f"{len(skipped)} of {len(files)} clips are unusable, too many to go on; the first: {skipped[0]}")
    for reason in skipped:
        warnings.warn(f"clip skipped: {reason}", ClipSkippedWarning, stacklevel=2)
    return clips, source


def _clip_features(path: Path, jmap, sk, unit: str, min_frames: int) -> np.ndarray:
    """One clip's features (T, D) float32; SMFError naming the file for a clip that cannot be used."""
    from ..motion.features import features_from_joints
    from ..motion.files import check_bones
    from ..motion.retarget import retarget_bvh

    joints = retarget_bvh(path, jmap, unit=unit)  # MotionFormatError / SMFError name the file
    if joints.shape[0] - 1 < min_frames:
        raise SMFError(f"{path}: {joints.shape[0] / sk.fps:.2f} s is too short; clips need at least "
                       f"{(min_frames + 1) / sk.fps:.2f} s")
    check_bones(joints, sk, str(path))
    feats = features_from_joints(joints, sk).astype(np.float32)
    if not np.isfinite(feats).all():
        raise SMFError(f"{path}: its motion gives non-finite features (a joint at the same place as its parent?)")
    return feats


__all__ = ["CAPTIONS_FILE", "Clip", "ClipSkippedWarning", "caption_from_name", "read_caption_csv", "read_clips"]
