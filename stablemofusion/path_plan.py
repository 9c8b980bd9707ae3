"""Paths from words: a prompt's path words ("walks in a circle", "turns around", "zigzags", "there and back") read
into a :class:`PathSpec` (the lexicon ``assets/lexicons/paths.json``), and the model's motion bent to follow it.

The model makes the motion of the prompt without its path words (a walk, a run, a 90-degree turn: what the corpus
holds); :func:`bend` then changes only the root's heading in the raw features, before the final stage:

- ``arc`` (circles, half circles, curves): the heading turns by the path's angle in proportion to the distance the
  root travels, so the walk becomes an arc of even curvature, and frames without travel (a wave after the walk)
  do not turn;
- ``turn`` (turn around, by N degrees, left or right): the model's own turn, scaled to the angle; where it made
  almost none, a smooth turn over the middle of the motion;
- ``zigzag``: the heading swings between +/- ZIGZAG_DEGREES over the distance, in ZIGZAG_LEGS legs, then goes
  straight on, facing the way it went;
- ``back`` (there and back): a half turn over the middle of the distance;
- ``strafe`` (sideways, facing forward): the model's turning removed, so the body keeps facing ahead.

Features are body-relative (velocities in the body's frame), so a new heading carries the root's path with it;
the footskate cleanup of the final stage then pins the feet. Bending costs no sampling step: a path prompt takes
the time of the same prompt without its path words. Without a length, a path gets its kind's (``seconds``).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np

from .footskate.cleanup import CLEANUP_CONTACTS
from .footskate.contacts import HML_FOOT_JOINTS, kinematic_contacts
from .motion.features import joints_from_features
from .motion.timeseries import smoothstep
from .motion.root import follow_path
from .motion.skeleton import get_skeleton

ZIGZAG_DEGREES = 45.0  # heading of a zigzag's legs either side of its direction
ZIGZAG_LEGS = 4  # legs of a zigzag
ZIGZAG_END = 0.85  # the legs take this part of the distance; the rest goes straight on, facing the way it went
TURN_SPAN = (0.3, 0.7)  # where a turn the model did not make is added: this part of the motion
BACK_SPAN = (0.42, 0.58)  # where a there-and-back turns: this part of the distance
MIN_MODEL_TURN = 30.0  # degrees: a smaller turn of the model's own is not scaled (a turn is added instead)
MIN_TRAVEL = 0.5  # m: a motion that travels less is bent over time, not distance
SKELETON = "humanml3d"  # the features bent here are HumanML3D's


@dataclass(frozen=True)
class PathSpec:
    """A prompt's path: ``kind`` (arc, turn, zigzag, back, strafe), ``angle`` its heading change in degrees
    (positive: to the left), ``side`` 'left' or 'right', ``prompt`` what the model is given (the path words
    replaced), ``words`` the words read, ``seconds`` the length when none is given (None: the model's estimate)."""

    kind: str
    angle: float
    side: str
    prompt: str
    words: str
    seconds: float | None


@lru_cache(maxsize=1)
def _lexicon() -> dict:
    data = json.loads((resources.files("stablemofusion") / "assets" / "lexicons" / "paths.json").read_text("utf-8"))
    data["compiled"] = [re.compile(f"(?:{p['pattern']}){data['direction_suffix']}") for p in data["paths"]]
    return data


def parse_path(prompt: str) -> PathSpec | None:
    """The path a prompt's words describe, or None (no path words)."""
    lex = _lexicon()
    text = prompt.lower()
    for entry, pattern in zip(lex["paths"], lex["compiled"]):
        m = pattern.search(text)
        if m is None or re.search(lex["body_words"] + r"(?:\W+\w+){0,2}\W*$", text[:m.start()]):
            continue  # no path words, or the path of a body part ("swings both arms back and forth")
        if entry.get("needs_move") and not re.search(lex["move_words"], text[:m.start()] + " " + text[m.end():]):
            continue
        words = m.group(0)
        where = words if re.search(lex["right_words"] + "|" + lex["left_words"], words) else text
        right, left = re.search(lex["right_words"], where), re.search(lex["left_words"], where)
        side = "right" if right and not (left and left.start() < right.start()) else "left"
        angle = float(m.group("degrees")) if entry["angle"] == "degrees" else float(entry["angle"])
        angle = -angle if side == "right" else angle
        gait = "run" if re.search(lex["run_words"], text) else "walk"
        outside = text[:m.start()] + " " + text[m.end():]
        move = "" if re.search(lex["move_words"], outside) else ("runs" if gait == "run" else "walks")
        model = entry["model"].format(side=side, move=move, words=prompt[m.start():m.end()])
        rest = prompt[:m.start()] + " " + model + " " + prompt[m.end():]
        rest = re.sub(lex["direction_words"], " ", rest, flags=re.IGNORECASE)
        rest = re.sub(r"\s+([,.;])", r"\1", re.sub(r"\s+", " ", rest)).strip(" ,")
        seconds = entry["seconds"][gait] if entry["seconds"] else None
        return PathSpec(entry["kind"], angle, side, rest or prompt, words.strip(), seconds)
    return None


def _progress(features: np.ndarray) -> np.ndarray:
    """(T,) how far along the motion each frame is, 0 .. 1: by the root's travelled distance, or by time for a
    motion that hardly travels."""
    speed = np.linalg.norm(features[:, 1:3], axis=-1)
    travelled = np.concatenate([[0.0], np.cumsum(speed[:-1])])
    if travelled[-1] < MIN_TRAVEL:
        return np.linspace(0.0, 1.0, len(features))
    return travelled / travelled[-1]


def heading_offset(spec: PathSpec, features: np.ndarray) -> np.ndarray:
    """(T,) radians (positive: to the left) added to the root heading of each frame of raw features (T, D), so that
    the body's facing (:func:`facing`) changes as ``spec`` says."""
    u = _progress(features)
    a = math.radians(spec.angle)
    face = facing(features)
    face = face - face[0]
    if spec.kind == "turn":
        if abs(math.degrees(face[-1])) >= MIN_MODEL_TURN:  # the model's own turn, scaled to the angle
            return face * (a / face[-1] - 1.0)
        t = np.linspace(0.0, 1.0, len(features))
        return a * smoothstep((t - TURN_SPAN[0]) / (TURN_SPAN[1] - TURN_SPAN[0])) - face
    if spec.kind == "strafe":  # keep facing ahead
        return -face
    if spec.kind == "arc":
        target = a * u
    elif spec.kind == "back":
        target = a * smoothstep((u - BACK_SPAN[0]) / (BACK_SPAN[1] - BACK_SPAN[0]))
    elif spec.kind == "zigzag":
        legs = np.clip(1.5 * np.sin(math.pi * ZIGZAG_LEGS * np.minimum(u / ZIGZAG_END, 1.0)), -1.0, 1.0)
        target = math.radians(ZIGZAG_DEGREES) * legs
    else:
        raise ValueError(f"unknown path kind {spec.kind!r}")
    return target - face[-1] * u  # the path's turning, less the model's own drift (its sway kept)


def facing(features: np.ndarray) -> np.ndarray:
    """(T,) the body's facing in radians (positive: to the left, unwrapped) of raw HumanML3D features (T, D): the
    root's heading (the yaw channel integrates half-angles of turns to the right) plus the facing of the hips in the
    root's frame (their root-relative positions)."""
    yaw = features[:, 0]
    heading = -2.0 * np.concatenate([[0.0], np.cumsum(yaw[:-1])])
    across = features[:, 4:7] - features[:, 7:10]  # left hip - right hip, root-relative, in the root's frame
    local = np.unwrap(np.arctan2(-across[:, 2], across[:, 0]))  # the facing (across x up) of the hips, about +Y
    return heading + local


def bend(features: np.ndarray, spec: PathSpec | None) -> np.ndarray:
    """Raw features (T, D) whose facing follows ``spec`` (a copy; ``features`` itself when ``spec`` is None). The
    body turns about its planted foot where one is planted (the root's path moved so that the foot stays where it
    stands), else about the root."""
    if spec is None or len(features) < 2:
        return features
    f = np.array(features, dtype=np.float64)
    extra = heading_offset(spec, f)
    path = _pivoted_path(f, extra)
    f[:-1, 0] -= np.diff(extra) / 2.0  # frame t's yaw velocity carries it to frame t + 1 (half-angles)
    f = follow_path(f, path)
    return f.astype(np.asarray(features).dtype, copy=False)


def _pivoted_path(features: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """(T, 2) the root's XZ path once the body is turned by ``extra`` (T,) radians more at each frame: each step
    turned with its frame, and while a foot is planted in the original motion, the root moved about that foot so
    that the foot stays put (its position: the mean of the planted foot joints)."""
    joints = joints_from_features(features, SKELETON)
    root = joints[:, 0, [0, 2]]
    feet = joints[:, list(HML_FOOT_JOINTS)][..., [0, 2]]  # (T, 4, 2)
    planted = kinematic_contacts(joints, get_skeleton(SKELETON).fps, config=CLEANUP_CONTACTS)  # (T, 4)
    c, s = np.cos(extra), np.sin(extra)

    def turn(k: slice, v: np.ndarray) -> np.ndarray:  # v (n, 2) turned about +Y by extra[k] (n,)
        return np.stack([c[k] * v[:, 0] + s[k] * v[:, 1], -s[k] * v[:, 0] + c[k] * v[:, 1]], -1)

    now, nxt = slice(0, len(root) - 1), slice(1, len(root))
    both = planted[:-1] & planted[1:]  # (T-1, 4): feet planted in frames t and t + 1
    count = both.sum(-1, keepdims=True)
    arm = (feet[:-1] * both[..., None]).sum(1) / np.maximum(count, 1) - root[:-1]  # (T-1, 2): root to that foot
    step = turn(nxt, root[1:] - root[:-1]) + np.where(count > 0, turn(now, arm) - turn(nxt, arm), 0.0)
    return np.concatenate([np.zeros((1, 2)), np.cumsum(step, axis=0)])


MAX_WAYPOINTS = 256  # an explicit path's most points
MAX_PATH_METRES = 200.0  # and its longest total length; and how far from the origin any point may lie
MAX_PATH_SPEED = 12.0  # m/s: the fastest a path's times may ask the body to move between two points (a sprinter's)
TANGENT_SPAN = 0.3  # m either side of a point over which an explicit path's direction there is taken


@dataclass(frozen=True, eq=False)
class Waypoints:
    """An explicit root path: ``points`` (K, 2) floor positions X, Z in metres (Y up; the motion starts at the first,
    facing the second), optional ``times`` (K,) seconds at which the root passes them (from 0, increasing). Equal
    and hashed by value (a request's path is part of what it asks for)."""

    points: np.ndarray
    times: np.ndarray | None = None

    def _key(self) -> tuple:
        return self.points.shape, self.points.tobytes(), None if self.times is None else self.times.tobytes()

    def __eq__(self, other) -> bool:
        return isinstance(other, Waypoints) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    @classmethod
    def read(cls, data) -> "Waypoints":
        """From JSON-like ``data``: a list of [x, z] points, or {"points": [[x, z], ...], "times": [...]}; SMFError
        naming the problem."""
        from .errors import SMFError

        body = data if isinstance(data, dict) else {"points": data}
        extra = set(body) - {"points", "times"}
        if extra:
            raise SMFError(f"a path has 'points' and optionally 'times', not {', '.join(sorted(extra))}")
        try:
            points = np.asarray(body.get("points"), dtype=np.float64)
        except (TypeError, ValueError):
            raise SMFError("path points must be [x, z] pairs of numbers (metres)") from None
        if points.ndim != 2 or points.shape[1] != 2 or not 2 <= len(points) <= MAX_WAYPOINTS:
            raise SMFError(f"a path is 2 to {MAX_WAYPOINTS} [x, z] points, got shape {points.shape}")
        if not np.isfinite(points).all():
            raise SMFError("path points must be finite numbers")
        if np.abs(points).max() > MAX_PATH_METRES:
            raise SMFError(f"path points must lie within {MAX_PATH_METRES:g} m of the origin, got "
                           f"{np.abs(points).max():.3g} m")
        steps = np.linalg.norm(np.diff(points, axis=0), axis=-1)
        if steps.sum() > MAX_PATH_METRES or steps.sum() < MIN_TRAVEL:
            raise SMFError(f"a path must be {MIN_TRAVEL:g} to {MAX_PATH_METRES:g} m long, got {steps.sum():.2f} m")
        if np.any(steps < 1e-6):
            raise SMFError("a path's consecutive points must differ")
        times = body.get("times")
        if times is not None:
            try:
                times = np.asarray(times, dtype=np.float64)
            except (TypeError, ValueError):
                raise SMFError("path times must be numbers (seconds)") from None
            if times.shape != (len(points),) or not np.isfinite(times).all() or times[0] != 0 \
                    or np.any(np.diff(times) <= 0):
                raise SMFError("path times are one per point, from 0, increasing (seconds)")
            speed = steps / np.diff(times)
            if speed.max() > MAX_PATH_SPEED:
                k = int(np.flatnonzero(speed > MAX_PATH_SPEED)[0])
                raise SMFError(f"a path's times ask for {speed[k]:.3g} m/s between points {k + 1} and {k + 2}; at most "
                               f"{MAX_PATH_SPEED:g} m/s")
        return cls(points, times)

    @property
    def length(self) -> float:
        """Metres along the path."""
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=-1).sum())

    def seconds(self, prompt: str) -> float:
        """How long following it takes: its last time, else its length at the prompt's gait's speed."""
        from .limits import LENGTH_MULTIPLE

        lex = _lexicon()
        seconds = float(self.times[-1]) if self.times is not None else \
            self.length / lex["speeds"]["run" if re.search(lex["run_words"], prompt.lower()) else "walk"]
        fps = get_skeleton(SKELETON).fps
        return max(1, round(seconds * fps / LENGTH_MULTIPLE)) * LENGTH_MULTIPLE / fps  # whole multiples of frames


def _along(points: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(N, 2) positions at arc lengths ``s`` (N,) metres along polyline ``points`` (K, 2)."""
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=-1))])
    s = np.clip(s, 0.0, cum[-1])
    return np.stack([np.interp(s, cum, points[:, 0]), np.interp(s, cum, points[:, 1])], -1)


def follow_waypoints(features: np.ndarray, path: Waypoints, fps: float) -> tuple[np.ndarray, float, np.ndarray]:
    """Raw features (T, D) whose root runs along ``path`` (at the motion's own pace, or at the path's times) facing
    its direction, in the features' frame (the path turned so that it starts along the body's first facing); and
    how to place the result in the path's frame: the facing (radians, positive to the left) and the floor position
    (2,) of its first frame."""
    f = np.array(features, dtype=np.float64)
    T = len(f)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path.points, axis=0), axis=-1))])
    if path.times is not None:  # arc length at each frame from the times (constant speed between points)
        s = np.interp(np.arange(T) / fps, path.times, cum)
    else:
        s = _progress(f) * cum[-1]
    p = _along(path.points, s)
    d = _along(path.points, s + TANGENT_SPAN) - _along(path.points, s - TANGENT_SPAN)
    heading = np.unwrap(np.arctan2(d[:, 0], d[:, 1]))  # facing of +Z is 0, of +X (left) is +pi/2
    face = facing(f)
    start = heading[0] - face[0]  # the path turned by -start starts along the body's first facing
    c, sn = math.cos(-start), math.sin(-start)
    rel = p - p[0]
    local = np.stack([c * rel[:, 0] + sn * rel[:, 1], -sn * rel[:, 0] + c * rel[:, 1]], -1)
    extra = (heading - start) - face
    extra -= extra[0]
    f[:-1, 0] -= np.diff(extra) / 2.0
    return follow_path(f, local), float(start), p[0].copy()


def waypoints_for(path, n: int) -> list["Waypoints | None"]:
    """``path`` of a text-to-motion call as one per prompt: None, one path (Waypoints or its JSON form) for all, or
    a list with one per prompt."""
    from .errors import SMFError

    if path is None:
        return [None] * n
    if isinstance(path, (list, tuple)) and path and (path[0] is None or isinstance(path[0], (Waypoints, dict))
                                                        or np.ndim(path[0]) == 2):
        if len(path) != n:
            raise SMFError(f"give one path for all prompts or one per prompt: {len(path)} paths for {n} prompts")
        return [None if p is None else p if isinstance(p, Waypoints) else Waypoints.read(p) for p in path]
    one = path if isinstance(path, Waypoints) else Waypoints.read(path)
    return [one] * n


def place(motion, start: float, origin: np.ndarray):
    """A rigid motion made along a path's features (its first frame at the floor's origin, facing +Z) turned by
    ``start`` radians (positive: left) and moved to ``origin`` (2,): into the path's frame."""
    from .motion.root import place_rigid_like

    return place_rigid_like(motion, 0, 0.0, np.zeros(2), -start / 2.0, origin)


def follow(raw: np.ndarray, spec: PathSpec | None, explicit: Waypoints | None, fps: float
           ) -> tuple[np.ndarray, tuple[float, np.ndarray] | None]:
    """Raw features (T, D) bent to an explicit path, with how to place the result in its frame (:func:`placed`), or
    to the words' path (``spec``; nothing to place)."""
    if explicit is not None:
        f, start, origin = follow_waypoints(raw, explicit, fps)
        return f, (start, origin)
    return bend(raw, spec), None


def placed(features: np.ndarray, motion, placing: tuple[float, np.ndarray] | None, rigid) -> tuple[np.ndarray, object]:
    """A finished motion (features, rigid body) put in its explicit path's frame (:func:`follow`'s ``placing``; as it
    is without one), its features written for the placed body (``rigid``: the pipeline's rigid fit settings)."""
    if placing is None:
        return features, motion
    from .motion.rigid import rigid_to_features

    motion = place(motion, *placing)
    return rigid_to_features(motion, features, rigid)[1], motion


@dataclass
class PromptPaths:
    """The paths of a text-to-motion call's prompts: each one's path words (``words``, None without), explicit path
    (``explicit``, None without) and the prompt its model is given (``asked``)."""

    words: list[PathSpec | None]
    explicit: list[Waypoints | None]
    asked: list[str]

    @classmethod
    def read(cls, prompts: list[str], path=None) -> "PromptPaths":
        words, asked = read_paths(prompts)
        return cls(words, waypoints_for(path, len(prompts)), asked)

    def seconds(self, prompts: list[str], secs: list, frames: list) -> list:
        """``secs`` with a path's length where neither seconds nor frames are given (the explicit path's, else the
        path words'); None where the model's estimate decides."""
        out = list(secs)
        for i, p in enumerate(prompts):
            if out[i] is None and frames[i] is None:
                if self.explicit[i] is not None:
                    out[i] = self.explicit[i].seconds(p)
                elif self.words[i] is not None and self.words[i].seconds is not None:
                    out[i] = self.words[i].seconds
        return out


def read_paths(prompts: list[str]) -> tuple[list[PathSpec | None], list[str]]:
    """Each prompt's path (None without path words) and the prompt its model is given."""
    specs = [parse_path(p) for p in prompts]
    return specs, [p if s is None else s.prompt for p, s in zip(prompts, specs)]


def path_segments(segments: list[tuple[str, int]]) -> tuple[list[tuple[str, int]], list[PathSpec | None]]:
    """A timeline's (prompt, frames) segments with the prompts its model is given, and each segment's path."""
    specs, asked = read_paths([p for p, _ in segments])
    return [(a, n) for a, (_, n) in zip(asked, segments)], specs


def bend_segments(features: np.ndarray, frames: list[int], specs: list[PathSpec | None]) -> np.ndarray:
    """Raw features (T, D) of consecutive segments of ``frames`` each, each segment bent by its path (a later
    segment continues from where the bent one leaves the body: features are body-relative)."""
    if all(s is None for s in specs):
        return features
    f = np.array(features, dtype=np.float64)
    a = 0
    for n, spec in zip(frames, specs):
        b = min(a + n, len(f))
        if spec is not None and b - a >= 2:
            f[a:b] = bend(f[a:b], spec)
        a = b
    return f


__all__ = ["PathSpec", "PromptPaths", "Waypoints", "bend", "follow", "follow_waypoints", "place", "placed", "waypoints_for", "bend_segments", "heading_offset", "parse_path", "path_segments", "read_paths"]
