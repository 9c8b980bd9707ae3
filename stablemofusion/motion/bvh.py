"""BVH motion capture files: a fast generic reader, forward kinematics and a writer.

Lengths in a :class:`BVH` are metres (``read_bvh`` converts them from the file's unit, recorded in
``BVH.unit``); angles in ``BVH.motion`` are degrees as in the file. Joints are in file (depth-first)
order, so every parent precedes its children.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import MotionFormatError, SMFError
from ..core.io import atomic_path
from ..core.limits import MAX_ABS_VALUE, MAX_FRAME_TIME_S, MIN_FRAME_TIME_S
from .kinematics import forward_kinematics as forward_kinematics_of_tree
from .rotation import matrix_to_euler, quat_to_matrix

UNIT_SCALES: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254}  # metres per unit
_CHANNELS = {f"{a}{k}".lower(): f"{a}{k}" for a in "XYZ" for k in ("position", "rotation")}
_AXIS = {"X": 0, "Y": 1, "Z": 2}


@dataclass
class BVH:
    """A parsed BVH file.

    ``names``: J joint names in file order (End Sites are not joints); ``parents``: (J,) int, -1 for the
    root; ``offsets``: (J, 3) metres; ``channels``: per-joint channel names in file order;
    ``end_sites``: joint index -> (3,) end-site offset in metres; ``frame_time``: seconds;
    ``motion``: (F, total_channels) channel values in file column order (position channels in metres,
    rotation channels in degrees); ``unit``: the unit the file was written in ("m", "cm", "mm", "inch").
    """

    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    channels: list[list[str]]
    end_sites: dict[int, np.ndarray]
    frame_time: float
    motion: np.ndarray
    unit: str = "m"

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def rotations(self, frames: slice | None = None) -> np.ndarray:
        """(F, J, 3, 3) local rotation matrices; each joint's rotation channels compose intrinsically
        in listed order ("Zrotation Xrotation Yrotation" -> Rz @ Rx @ Ry); identity where none."""
        motion = self.motion if frames is None else self.motion[frames]
        out = np.broadcast_to(np.eye(3), (len(motion), self.num_joints, 3, 3)).copy()
        groups: dict[str, tuple[list[int], list[list[int]]]] = {}  # axis sequence -> joints, columns
        for j, chans in _channel_columns(self.channels):
            rc = [(c, name[0]) for c, name in chans if name.endswith("rotation")]
            if rc:
                joints, cols = groups.setdefault("".join(a for _, a in rc), ([], []))
                joints.append(j)
                cols.append([c for c, _ in rc])
        for seq, (joints, cols) in groups.items():
            angles = motion[:, np.array(cols)].reshape(-1, len(seq))  # (F * Jg, k) degrees
            out[:, joints] = _euler_matrices(seq, angles).reshape(len(motion), len(joints), 3, 3)
        return out

    def translations(self, frames: slice | None = None) -> np.ndarray:
        """(F, J, 3) local translations in metres: the offset, each axis replaced by its position
        channel where the joint has one."""
        motion = self.motion if frames is None else self.motion[frames]
        out = np.broadcast_to(self.offsets, (len(motion), self.num_joints, 3)).copy()
        for j, chans in _channel_columns(self.channels):
            for c, name in chans:
                if name.endswith("position"):
                    out[:, j, _AXIS[name[0]]] = motion[:, c]
        return out


def _channel_columns(channels: list[list[str]]) -> list[tuple[int, list[tuple[int, str]]]]:
    """Per joint: (joint index, [(motion column, channel name), ...])."""
    out, start = [], 0
    for j, chans in enumerate(channels):
        out.append((j, list(enumerate(chans, start))))
        start += len(chans)
    return out


def _euler_matrices(seq: str, angles: np.ndarray) -> np.ndarray:
    """(N, 3, 3) matrices of intrinsic rotations about the axes in ``seq`` by ``angles`` (N, k) degrees
    (Rz @ Rx @ Ry for "ZXY"), composed as quaternions elementwise (several times faster than scipy)."""
    half = np.radians(angles) / 2
    cos, sin = np.cos(half), np.sin(half)
    w, v = cos[:, 0], [np.zeros(len(angles)) for _ in range(3)]
    v[_AXIS[seq[0]]] = sin[:, 0]
    for i, a in enumerate(seq[1:], 1):  # q <- q * (cos, sin * e_k): w' = w c - v_k s, v' = v c + s (w e_k + v x e_k)
        c, s = cos[:, i], sin[:, i]
        k = _AXIS[a]
        m, n = (k + 1) % 3, (k + 2) % 3  # (v x e_k)_m = v_n, (v x e_k)_n = -v_m: no np.cross (slow on columns)
        nv = [v[0], v[1], v[2]]
        nv[k], nv[m], nv[n] = v[k] * c + s * w, v[m] * c + s * v[n], v[n] * c - s * v[m]
        w, v = w * c - v[k] * s, nv
    x, y, z = v
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).reshape(-1, 3, 3)


class _Tokens:
    """Whitespace tokens of the HIERARCHY lines, with 1-based line numbers, for error messages."""

    def __init__(self, lines: list[str], where: str):
        self.toks = [(t, n) for n, line in enumerate(lines, 1) for t in line.split()]
        self.i, self.where = 0, where
        self.last = self.toks[-1][1] if self.toks else 1  # where an unexpected end is reported

    def fail(self, msg: str, line: int | None = None) -> MotionFormatError:
        return MotionFormatError(f"{self.where}:{self.last if line is None else line}: {msg}")

    def next(self) -> tuple[str, int]:
        if self.i >= len(self.toks):
            raise self.fail("file ends inside the HIERARCHY block")
        self.i += 1
        return self.toks[self.i - 1]

    def rest_of_line(self, line: int) -> str:
        """The remaining tokens of ``line`` up to a "{", joined by spaces (joint names may have spaces)."""
        words = []
        while self.i < len(self.toks) and self.toks[self.i][1] == line and self.toks[self.i][0] != "{":
            words.append(self.toks[self.i][0])
            self.i += 1
        return " ".join(words)

    def expect(self, word: str) -> int:
        tok, n = self.next()
        if tok != word:
            raise self.fail(f"expected '{word}', got '{tok}'", n)
        return n

    def number(self, what: str) -> float:
        tok, n = self.next()
        try:
            return float(tok)
        except ValueError:
            raise self.fail(f"expected a number after {what}, got '{tok}'", n) from None


def _parse_hierarchy(tk: _Tokens):
    """Parse HIERARCHY ... up to the closing brace of the root; returns the skeleton pieces."""
    tk.expect("HIERARCHY")
    tok, n = tk.next()
    if tok != "ROOT":
        raise tk.fail(f"expected 'ROOT', got '{tok}'", n)
    names, parents, offsets, channels, end_sites = [], [], [], [], {}
    stack: list[int | None] = []  # open blocks: joint index, or None for an End Site
    keyword, line = "ROOT", n
    while True:
        if (keyword == "ROOT" and not stack) or (keyword == "JOINT" and stack and stack[-1] is not None):
            name = tk.rest_of_line(line)
            if not name:
                raise tk.fail(f"{keyword} without a name", line)
            tk.expect("{")
            parents.append(stack[-1] if stack else -1)
            names.append(name)
            offsets.append(np.zeros(3))
            channels.append([])
            stack.append(len(names) - 1)
        elif keyword == "End":
            tk.rest_of_line(line)  # "Site"
            if not stack or stack[-1] is None:
                raise tk.fail("unexpected token 'End'", line)
            tk.expect("{")
            end_sites[stack[-1]] = np.zeros(3)
            stack.append(None)
        elif keyword == "OFFSET" and stack:
            value = np.array([tk.number("OFFSET") for _ in range(3)])
            if stack[-1] is None:
                end_sites[stack[-2]] = value
            else:
                offsets[stack[-1]] = value
        elif keyword == "CHANNELS" and stack and stack[-1] is not None:
            count = tk.number("CHANNELS")
            if count != int(count) or count < 0:
                raise tk.fail(f"bad channel count '{count:g}'", line)
            chans = []
            for _ in range(int(count)):
                tok, n = tk.next()
                if tok.lower() not in _CHANNELS:
                    raise tk.fail(f"unknown channel '{tok}'", n)
                chans.append(_CHANNELS[tok.lower()])
            channels[stack[-1]] = chans
        elif keyword == "}" and stack:
            stack.pop()
            if not stack:
                return names, parents, offsets, channels, end_sites
        else:
            raise tk.fail(f"unexpected token '{keyword}'", line)
        keyword, line = tk.next()


def read_bvh(path: str | os.PathLike, *, unit: str = "auto") -> BVH:
    """Read a BVH file; lengths are converted to metres.

    ``unit``: the file's length unit, one of "auto", "m", "cm", "mm", "inch". "auto" takes the vertical
    (Y) extent of the rest pose (offsets and end sites): < 3 -> metres, < 300 -> centimetres, else mm.
    Raises ``MotionFormatError`` ("file:line: message") for malformed files.
    """
    if unit != "auto" and unit not in UNIT_SCALES:
        raise SMFError(f"unknown unit '{unit}'; expected one of auto, {', '.join(UNIT_SCALES)}")
    path = Path(path)
    if not path.is_file():
        raise SMFError(f"no such file: {path}")
    where = str(path)
    text = path.read_bytes().decode("utf-8", errors="replace")
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    lines = text.split("\n")
    m = next((i for i, s in enumerate(lines) if s.strip() == "MOTION"), len(lines))
    tk = _Tokens(lines[:m], where)
    names, parents, offsets, channels, end_sites = _parse_hierarchy(tk)
    if tk.i < len(tk.toks):
        tok, n = tk.toks[tk.i]
        raise tk.fail("more than one ROOT is not supported" if tok == "ROOT" else f"unexpected token '{tok}'", n)
    if m == len(lines):
        raise tk.fail("missing MOTION section")

    # "Frames: N" and "Frame Time: t" headers, then one line of values per frame.
    k = m + 1
    header: list[float] = []
    header_lines: list[int] = []
    for label, conv in (("Frames:", int), ("Frame Time:", float)):
        while k < len(lines) and not lines[k].strip():
            k += 1
        if k == len(lines):
            raise MotionFormatError(f"{where}:{k}: file ends before '{label}'")
        s = lines[k].strip()
        try:
            if not s.startswith(label):
                raise ValueError
            header.append(conv(s[len(label):]))
            header_lines.append(k + 1)
        except ValueError:
            raise MotionFormatError(f"{where}:{k + 1}: expected '{label} <number>', got '{s[:40]}'") from None
        k += 1
    frames, frame_time = int(header[0]), header[1]
    if frames < 0 or not (np.isfinite(frame_time) and frame_time > 0):
        raise MotionFormatError(f"{where}:{header_lines[0]}: bad 'Frames:' or 'Frame Time:' value")
    if not MIN_FRAME_TIME_S <= frame_time <= MAX_FRAME_TIME_S:
        raise MotionFormatError(f"{where}:{header_lines[1]}: 'Frame Time: {frame_time:g}' must be between "
                                f"{MIN_FRAME_TIME_S:g} and {MAX_FRAME_TIME_S:g} s (1 to 1000 frames per second)")
    n_chan = sum(len(c) for c in channels)
    motion = _parse_motion(lines, k, n_chan, where)
    if len(motion) != frames:
        raise MotionFormatError(f"{where}:{header_lines[0]}: 'Frames: {frames}' but {len(motion)} frames follow")

    offsets_a = np.array(offsets, dtype=np.float64).reshape(-1, 3)
    if not (np.isfinite(offsets_a).all() and np.abs(offsets_a).max(initial=0.0) <= MAX_ABS_VALUE):
        raise MotionFormatError(f"{where}:1: OFFSET values must be finite numbers of at most {MAX_ABS_VALUE:g}")
    parents_a = np.array(parents, dtype=np.int64)
    if unit == "auto":
        unit = _detect_unit(offsets_a, parents_a, end_sites)
    scale = UNIT_SCALES[unit]
    pos_cols = [c for c, name in enumerate(n for ch in channels for n in ch) if name.endswith("position")]
    if scale != 1.0:
        motion[:, pos_cols] *= scale
    return BVH(names=names, parents=parents_a, offsets=offsets_a * scale, channels=channels,
               end_sites={j: v * scale for j, v in end_sites.items()}, frame_time=frame_time,
               motion=motion, unit=unit)


def _parse_motion(lines: list[str], start: int, n_chan: int, where: str) -> np.ndarray:
    """(F, n_chan) values of ``lines[start:]`` (blank lines skipped), each a finite number of at most
    :data:`~stablemofusion.core.limits.MAX_ABS_VALUE`, parsed by one numpy call; on error a slow pass finds the offending
    line."""
    body = lines[start:]
    if not any(s.strip() for s in body):
        return np.empty((0, n_chan))
    try:
        motion = np.loadtxt(body, dtype=np.float64, comments=None, ndmin=2)
        if motion.shape[1] == n_chan and np.isfinite(motion).all() and np.abs(motion).max() <= MAX_ABS_VALUE:
            return motion
    except ValueError:
        pass
    for i, s in enumerate(body, start + 1):
        vals = s.split()
        if not vals:
            continue
        if len(vals) != n_chan:
            raise MotionFormatError(f"{where}:{i}: expected {n_chan} values per frame, got {len(vals)}")
        for v in vals:
            try:
                ok = np.isfinite(float(v))
            except ValueError:
                ok = False
            if not ok:
                raise MotionFormatError(f"{where}:{i}: non-numeric value '{v[:20]}'")
            if abs(float(v)) > MAX_ABS_VALUE:
                raise MotionFormatError(f"{where}:{i}: value '{v[:20]}' is beyond +-{MAX_ABS_VALUE:g}")
    raise MotionFormatError(f"{where}:{start + 1}: unreadable MOTION data")  # pragma: no cover


def _rest_positions(offsets: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """(J, 3) rest-pose positions: offsets accumulated along the hierarchy."""
    return forward_kinematics_of_tree(offsets, None, offsets[0], parents)


def _detect_unit(offsets: np.ndarray, parents: np.ndarray, end_sites: dict[int, np.ndarray]) -> str:
    pos = _rest_positions(offsets, parents)
    pts = np.concatenate([pos, [pos[j] + v for j, v in end_sites.items()]]) if end_sites else pos
    height = float(np.ptp(pts[:, 1])) if len(pts) else 0.0
    return "m" if height < 3 else "cm" if height < 300 else "mm"


def forward_kinematics(bvh: BVH, frames: slice | None = None) -> np.ndarray:
    """(F, J, 3) world joint positions in metres (``frames`` selects motion rows): the channels as local
    rotations and translations, through :func:`stablemofusion.motion.kinematics.forward_kinematics`."""
    if np.any(bvh.parents >= np.arange(len(bvh.parents))):
        raise MotionFormatError("BVH joints must come after their parents")
    trans = bvh.translations(frames)
    return forward_kinematics_of_tree(trans, bvh.rotations(frames), trans[:, 0], bvh.parents)


BVH_ORDER = "ZXY"  # the rotation channels of the BVH files we write: R = Rz Rx Ry


def write_bvh(path: str | os.PathLike, *, names: list[str], parents, offsets, rotations, root_positions,
              frame_time: float, end_sites: dict[int, np.ndarray] | None = None, order: str = BVH_ORDER,
              precision: int = 6) -> None:
    """Write a BVH file in metres, atomically; the arguments are those of :func:`format_bvh`."""
    text = format_bvh(names=names, parents=parents, offsets=offsets, rotations=rotations,
                      root_positions=root_positions, frame_time=frame_time, end_sites=end_sites, order=order,
                      precision=precision)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def format_bvh(*, names: list[str], parents, offsets, rotations, root_positions, frame_time: float,
               end_sites: dict[int, np.ndarray] | None = None, order: str = BVH_ORDER, precision: int = 6) -> str:
    """The text of a BVH file in metres.

    ``parents`` (J,) with -1 for the single root and parents before children; ``offsets`` (J, 3) metres;
    ``rotations`` (F, J, 3, 3) local rotation matrices or (F, J, 4) unit quaternions (w, x, y, z);
    ``root_positions`` (F, 3) metres; ``order``: intrinsic Euler order of the rotation channels. The root
    gets 6 channels (positions, then rotations), other joints 3. Leaf joints get an End Site from
    ``end_sites`` or 0.05 m along their own offset (+Y if that is zero). Joints are written depth-first
    (children in index order), which is the order ``read_bvh`` returns them in.
    """
    parents = np.asarray(parents, dtype=np.int64)
    offsets = np.asarray(offsets, dtype=np.float64)
    rotations = np.asarray(rotations, dtype=np.float64)
    root_positions = np.asarray(root_positions, dtype=np.float64)
    J = len(names)
    order = order.upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise SMFError(f"order must be a permutation of XYZ, got '{order}'")
    if parents.shape != (J,) or offsets.shape != (J, 3):
        raise MotionFormatError(f"expected parents ({J},) and offsets ({J}, 3), got {parents.shape}, {offsets.shape}")
    if (parents < 0).sum() != 1 or parents[0] != -1 or np.any(parents[1:] >= np.arange(1, J)) or np.any(parents < -1):
        raise MotionFormatError("parents must have one root (-1) at index 0 and list parents before children")
    if rotations.ndim != 4 and not (rotations.ndim == 3 and rotations.shape[2] == 4):
        raise MotionFormatError(f"rotations must be (F, {J}, 3, 3) or (F, {J}, 4), got {rotations.shape}")
    F = rotations.shape[0]
    if rotations.shape[1] != J or (rotations.ndim == 4 and rotations.shape[2:] != (3, 3)):
        raise MotionFormatError(f"rotations must be (F, {J}, 3, 3) or (F, {J}, 4), got {rotations.shape}")
    if root_positions.shape != (F, 3):
        raise MotionFormatError(f"root_positions must be ({F}, 3), got {root_positions.shape}")
    if not (frame_time > 0):
        raise SMFError(f"frame_time must be positive, got {frame_time}")
    if any(not n.strip() or any(c in n for c in "{}\r\n") for n in names):
        raise MotionFormatError("joint names must be non-empty, without braces or line breaks")
    if not (np.isfinite(rotations).all() and np.isfinite(root_positions).all() and np.isfinite(offsets).all()):
        raise MotionFormatError("non-finite values in rotations, root_positions or offsets")
    if rotations.ndim == 3 and np.any(np.linalg.norm(rotations, axis=-1) < 1e-8):
        raise MotionFormatError("zero-norm quaternion in rotations")

    if rotations.ndim == 3:
        q = rotations.reshape(-1, 4)
        matrices = quat_to_matrix(q / np.linalg.norm(q, axis=-1, keepdims=True))
    else:
        matrices = rotations.reshape(-1, 3, 3)
    euler = matrix_to_euler(matrices, order).reshape(F, J, 3)  # gimbal lock: the angles still give the rotation

    children: list[list[int]] = [[] for _ in range(J)]
    for j in range(1, J):
        children[parents[j]].append(j)

    def num(v: np.ndarray) -> str:
        return " ".join(f"{x + 0.0:.{precision}f}" for x in np.round(v, precision))
    rot_chans = " ".join(f"{a}rotation" for a in order)
    out = ["HIERARCHY"]
    written: list[int] = []

    def emit(j: int, depth: int) -> None:
        ind = "\t" * depth
        written.append(j)
        out.append(f"{ind}{'ROOT' if j == 0 else 'JOINT'} {names[j]}")
        out.append(f"{ind}{{")
        out.append(f"{ind}\tOFFSET {num(offsets[j])}")
        out.append(f"{ind}\tCHANNELS 6 Xposition Yposition Zposition {rot_chans}" if j == 0
                   else f"{ind}\tCHANNELS 3 {rot_chans}")
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:
            site = end_sites.get(j) if end_sites else None
            if site is None:
                length = np.linalg.norm(offsets[j])
                site = offsets[j] * (0.05 / length) if length > 1e-9 else np.array([0.0, 0.05, 0.0])
            out.extend([f"{ind}\tEnd Site", f"{ind}\t{{", f"{ind}\t\tOFFSET {num(site)}", f"{ind}\t}}"])
        out.append(f"{ind}}}")

    emit(0, 0)
    data = np.concatenate([root_positions, euler[:, written].reshape(F, -1)], axis=1)
    data = np.round(data, precision) + 0.0  # no "-0.000000"
    row = " ".join([f"%.{precision}f"] * data.shape[1])
    out += ["MOTION", f"Frames: {F}", f"Frame Time: {frame_time:.9g}"]
    out += [row % tuple(r) for r in data.tolist()]
    return "\n".join(out) + "\n"
