"""The HumanML3D folder layout (also KIT-ML and our own corpora).

::

    root/new_joints/<id>.npy       (T, J, 3) joint positions
    root/new_joint_vecs/<id>.npy   (T, D) features (D = 263 HumanML3D, 251 KIT)
    root/texts/<id>.txt            one caption a line: ``caption#word/POS ...#start_sec#end_sec``
    root/Mean.npy, root/Std.npy    (D,) feature statistics (Std with one value per feature group)
    root/{train,val,test,all}.txt  one id a line; mirrored copies are ids prefixed with ``M``

A caption with ``0.0#0.0`` describes the whole clip, otherwise the sub-clip [start, end) seconds.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ..core.errors import MotionFormatError, SMFError
from ..core.io import save_npy, write_text
from ..motion.features import feature_slices
from ..motion.skeleton import HUMANML3D, KIT, Skeleton, get_skeleton

FEATURES_DIR = "new_joint_vecs"
JOINTS_DIR = "new_joints"
TEXTS_DIR = "texts"
MEAN_FILE = "Mean.npy"
STD_FILE = "Std.npy"
SPLITS = ("train", "val", "test", "all")


@dataclass
class CaptionLine:
    """One caption: text, ``word/POS`` tokens, and the described range in seconds (0, 0 = whole clip)."""

    caption: str
    tokens: list[str] = field(default_factory=list)
    start: float = 0.0
    end: float = 0.0

    @property
    def whole_clip(self) -> bool:
        return self.start == 0.0 and self.end == 0.0


def _time(value: str, what: str, where: str) -> float:
    try:
        t = float(value)
    except ValueError:
        raise MotionFormatError(f"{where}: {what} time {value!r} is not a number") from None
    return 0.0 if math.isnan(t) else t  # the official loader reads NaN as 0


def parse_text_line(line: str, where: str = "<text>") -> CaptionLine:
    """Parse ``caption#tokens#start#end``; ``where`` (e.g. ``texts/000000.txt:3``) prefixes errors.

    A ``#`` inside the caption is kept (the last three fields are tokens and times).
    """
    parts = line.rstrip("\r\n").split("#")
    if len(parts) < 4:
        raise MotionFormatError(f"{where}: expected 'caption#tokens#start#end', got {len(parts)} field(s)")
    caption = "#".join(parts[:-3]).strip()
    if not caption:
        raise MotionFormatError(f"{where}: empty caption")
    return CaptionLine(caption, parts[-3].split(), _time(parts[-2], "start", where), _time(parts[-1], "end", where))


def format_text_line(line: CaptionLine) -> str:
    """Inverse of :func:`parse_text_line` (no trailing newline)."""
    if any(c in s for s in (line.caption, *line.tokens) for c in "\r\n"):
        raise MotionFormatError(f"caption or tokens contain a line break: {line.caption!r}")
    if any("#" in t for t in line.tokens):
        raise MotionFormatError(f"tokens must not contain '#': {line.tokens!r}")
    return f"{line.caption}#{' '.join(line.tokens)}#{float(line.start)!r}#{float(line.end)!r}"


def read_texts(path: str | os.PathLike) -> list[CaptionLine]:
    """Read a ``texts/<id>.txt`` file; blank lines are skipped, a malformed one names ``file:line``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SMFError(f"missing caption file {path}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise MotionFormatError(f"{path}: cannot read ({e.__class__.__name__})") from None
    return [parse_text_line(s, f"{path}:{n}") for n, s in enumerate(text.splitlines(), 1) if s.strip()]


def mean_std(features_list: Iterable[np.ndarray],
             skeleton: str | Skeleton = "humanml3d") -> tuple[np.ndarray, np.ndarray]:
    """Feature statistics like HumanML3D's ``mean_variance`` (feature bias 1): (D,) mean, (D,) std.

    The mean is per dimension; the std is the per-dimension std averaged within each feature group (root yaw
    velocity, root XZ velocity, root height, positions, rotations, velocities, contacts), over all frames.
    """
    sk = get_skeleton(skeleton)
    arrays = [np.asarray(x, dtype=np.float64) for x in features_list]
    if not arrays:
        raise SMFError("mean_std: no motions given")
    for i, x in enumerate(arrays):
        if x.ndim != 2 or x.shape[1] != sk.feature_dim:
            raise MotionFormatError(f"mean_std: motion {i} has shape {x.shape}, expected (T, {sk.feature_dim})")
        if not np.isfinite(x).all():
            raise MotionFormatError(f"mean_std: motion {i} contains NaN or inf")
    data = np.concatenate(arrays, axis=0)
    mean, std = data.mean(axis=0), data.std(axis=0)
    for _, s in feature_slices(sk).items():
        std[s] = std[s].mean()
    return mean, std


def _skeleton_for_dim(dim: int, where: Path) -> Skeleton:
    for sk in (HUMANML3D, KIT):
        if sk.feature_dim == dim:
            return sk
    raise MotionFormatError(f"{where}: {dim} features match no skeleton (263 = humanml3d, 251 = kit)")


class MotionLayout:
    """A HumanML3D-style motion/text folder. The skeleton is given or inferred from ``Mean.npy``'s length."""

    def __init__(self, root: str | os.PathLike, skeleton: str | Skeleton | None = None):
        self.root = Path(root)
        self._skeleton = None if skeleton is None else get_skeleton(skeleton)
        self._stats: dict[str, np.ndarray] = {}

    def __repr__(self) -> str:
        return f"MotionLayout({str(self.root)!r})"

    # paths
    @property
    def features_dir(self) -> Path:
        return self.root / FEATURES_DIR

    @property
    def joints_dir(self) -> Path:
        return self.root / JOINTS_DIR

    @property
    def texts_dir(self) -> Path:
        return self.root / TEXTS_DIR

    def split_path(self, split: str) -> Path:
        return self.root / (split if split.endswith(".txt") else f"{split}.txt")

    @property
    def skeleton(self) -> Skeleton:
        if self._skeleton is None:
            path = self.root / MEAN_FILE
            if not path.is_file():
                raise SMFError(f"missing {path}: cannot infer the skeleton (pass skeleton='humanml3d' or 'kit')")
            self._skeleton = _skeleton_for_dim(self._load_stat(MEAN_FILE, check_dim=False).shape[0], path)
        return self._skeleton

    # checks and reads
    def validate(self) -> "MotionLayout":
        """Check the folders and statistics a dataset needs (``new_joints`` is optional); return self."""
        if not self.root.is_dir():
            raise SMFError(f"motion data folder {self.root} does not exist")
        for name in (MEAN_FILE, STD_FILE):
            if not (self.root / name).is_file():
                raise SMFError(f"missing {self.root / name}")
        for d in (self.features_dir, self.texts_dir):
            if not d.is_dir():
                raise SMFError(f"missing folder {d}")
        _ = self.mean, self.std
        return self

    def _load_stat(self, name: str, check_dim: bool = True) -> np.ndarray:
        if name in self._stats:
            return self._stats[name]
        path = self.root / name
        if not path.is_file():
            raise SMFError(f"missing {path}")
        arr = self._load_npy(path)
        if arr.ndim != 1:
            raise MotionFormatError(f"{path}: expected shape (D,), got {arr.shape}")
        if check_dim and arr.shape[0] != self.skeleton.feature_dim:
            raise MotionFormatError(f"{path}: expected shape ({self.skeleton.feature_dim},) for skeleton "
                                    f"{self.skeleton.name}, got {arr.shape}")
        if not np.isfinite(arr).all() or (name == STD_FILE and (arr <= 0).any()):
            raise MotionFormatError(f"{path}: values must be finite" + (" and positive" if name == STD_FILE else ""))
        if check_dim:
            self._stats[name] = arr
        return arr

    @property
    def mean(self) -> np.ndarray:
        """(D,) per-dimension feature mean from Mean.npy (as stored, float32 in HumanML3D)."""
        return self._load_stat(MEAN_FILE)

    @property
    def std(self) -> np.ndarray:
        """(D,) feature std from Std.npy (without any feature bias)."""
        return self._load_stat(STD_FILE)

    def ids(self, split: str) -> list[str]:
        """Ids listed in ``<split>.txt`` in file order (blank lines skipped)."""
        path = self.split_path(split)
        if not path.is_file():
            have = sorted(p.stem for p in self.root.glob("*.txt")) if self.root.is_dir() else []
            raise SMFError(f"missing split file {path}" + (f" (found: {', '.join(have)})" if have else ""))
        return [s.strip() for s in path.read_text(encoding="utf-8").splitlines() if s.strip()]

    @staticmethod
    def _load_npy(path: Path) -> np.ndarray:
        try:
            arr = np.load(path, allow_pickle=False)
        except FileNotFoundError:
            raise SMFError(f"missing {path}") from None
        except Exception as e:  # noqa: BLE001 - numpy raises many types for broken files
            raise MotionFormatError(f"{path}: not a readable .npy array ({e.__class__.__name__})") from None
        if not np.issubdtype(arr.dtype, np.number):
            raise MotionFormatError(f"{path}: array of dtype {arr.dtype} is not numeric")
        return arr

    def load_features(self, motion_id: str) -> np.ndarray:
        """(T, D) features of ``motion_id`` as stored; wrong width or NaN raise naming the file."""
        path = self.features_dir / f"{motion_id}.npy"
        arr = self._load_npy(path)
        D = self.skeleton.feature_dim
        if arr.ndim != 2 or arr.shape[1] != D:
            raise MotionFormatError(f"{path}: expected features of shape (T, {D}), got {arr.shape}")
        if not np.isfinite(arr).all():
            raise MotionFormatError(f"{path}: features contain NaN or inf")
        return arr

    def load_joints(self, motion_id: str) -> np.ndarray:
        """(T, J, 3) joint positions of ``motion_id`` as stored."""
        path = self.joints_dir / f"{motion_id}.npy"
        arr = self._load_npy(path)
        J = self.skeleton.num_joints
        if arr.ndim != 3 or arr.shape[1:] != (J, 3):
            raise MotionFormatError(f"{path}: expected joints of shape (T, {J}, 3), got {arr.shape}")
        return arr

    def load_texts(self, motion_id: str) -> list[CaptionLine]:
        return read_texts(self.texts_dir / f"{motion_id}.txt")

    # writes (atomic), for corpus builders
    def write_split(self, name: str, ids: Sequence[str]) -> Path:
        bad = [i for i in ids if not i or i != i.strip() or any(c.isspace() for c in i)]
        if bad:
            raise SMFError(f"invalid motion id(s) for split {name}: {bad[:5]!r}")
        path = self.split_path(name)
        write_text(path, "".join(f"{i}\n" for i in ids))
        return path

    def write_mean_std(self, mean: np.ndarray, std: np.ndarray) -> None:
        """Save (D,) Mean.npy / Std.npy as float32; D must match the skeleton (inferred when not given)."""
        mean, std = np.asarray(mean, dtype=np.float32), np.asarray(std, dtype=np.float32)
        if mean.ndim != 1 or mean.shape != std.shape:
            raise MotionFormatError(f"mean and std must both have shape (D,), got {mean.shape} and {std.shape}")
        if self._skeleton is None:
            self._skeleton = _skeleton_for_dim(mean.shape[0], self.root / MEAN_FILE)
        if mean.shape[0] != self._skeleton.feature_dim:
            raise MotionFormatError(f"mean/std have {mean.shape[0]} dims, skeleton {self._skeleton.name} "
                                    f"needs {self._skeleton.feature_dim}")
        if not (np.isfinite(mean).all() and np.isfinite(std).all() and (std > 0).all()):
            raise MotionFormatError("mean/std must be finite and std positive (a feature group has no variance?)")
        save_npy(self.root / MEAN_FILE, mean)
        save_npy(self.root / STD_FILE, std)
        self._stats.clear()

    def write_features(self, motion_id: str, features: np.ndarray) -> Path:
        path = self.features_dir / f"{motion_id}.npy"
        save_npy(path, np.asarray(features, dtype=np.float32))
        return path

    def write_texts(self, motion_id: str, lines: Sequence[CaptionLine]) -> Path:
        path = self.texts_dir / f"{motion_id}.txt"
        write_text(path, "".join(format_text_line(c) + "\n" for c in lines))
        return path
