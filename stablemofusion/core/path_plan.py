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
the time of the same prompt without its path words. Without a length, a path gets its kind's (``seconds``), spread
across seeds by the pipeline (:func:`~stablemofusion.core.sequence_plan.spread_seconds`).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np

from ..footskate.cleanup import CLEANUP_CONTACTS
from ..footskate.contacts import HML_FOOT_JOINTS, contacts_of_feet
from ..motion import timeseries as ts
from ..motion.arrays import namespace
from ..motion.features import joints_from_features
from ..motion.root import follow_path, headings
from ..motion.skeleton import get_skeleton

ZIGZAG_DEGREES = 45.0  # heading of a zigzag's legs either side of its direction
ZIGZAG_LEGS = 4  # legs of a zigzag
ZIGZAG_END = 0.85  # the legs take this part of the distance; the rest goes straight on, facing the way it went
TURN_SPAN = (0.3, 0.7)  # where a turn the model did not make is added: this part of the motion
BACK_SPAN = (0.42, 0.58)  # where a there-and-back turns: this part of the distance
MIN_MODEL_TURN = 30.0  # degrees: a smaller turn of the model's own is not scaled (a turn is added instead)
MIN_TRAVEL = 0.5  # m: a motion that travels less is bent over time, not distance
SKELETON = "humanml3d"  # the features bent here are HumanML3D's
KINDS = ("arc", "turn", "zigzag", "back", "strafe")  # a path's kind as the number the bending graph takes


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


def progress(features):
    """(B, T) how far along its motion each frame is, 0 .. 1, of raw features (B, T, D): by the root's travelled
    distance, or by time for a motion that travels less than MIN_TRAVEL."""
    xp = namespace(features)
    speed = ts.norm(features[..., 1:3])
    travelled = xp.concat([xp.zeros_like(speed[:, :1]), xp.cumulative_sum(speed[:, :-1], axis=1)], axis=1)
    total = travelled[:, -1:]
    by_time = xp.astype(ts.frames(features), features.dtype) / xp.astype(ts.count(features) - 1, features.dtype)
    return xp.where(total < ts.const(total, MIN_TRAVEL), by_time[None],
                    travelled / xp.where(total > 0, total, xp.ones_like(total)))


def facing(features):
    """(B, T) the body's facing in radians (positive: to the left, unwrapped) of raw HumanML3D features (B, T, D):
    the root's heading (the yaw channel integrates half-angles of turns to the right) plus the facing of the hips in
    the root's frame (their root-relative positions)."""
    across = features[..., 4:7] - features[..., 7:10]  # left hip - right hip, root-relative, in the root's frame
    local = ts.unwrap(ts.atan2(-across[..., 2], across[..., 0]))  # the facing (across x up) of the hips, about +Y
    return -2.0 * headings(features) + local


def heading_offset(kind, angle, features):
    """(B, T) radians (positive: to the left) added to the root heading of each frame of raw features (B, T, D) so
    that the body's facing (:func:`facing`) changes as a path of ``kind`` (B,) (an index into KINDS) and ``angle``
    (B,) radians says. Every kind is computed and each motion takes its own: no branch, so it runs as a graph."""
    xp = namespace(features)
    u = progress(features)
    a = angle[:, None]
    face = facing(features)
    face = face - face[:, :1]
    own = face[:, -1:]  # the model's own turn
    t = xp.astype(ts.frames(features), features.dtype)[None] / xp.astype(ts.count(features) - 1, features.dtype)
    scaled = face * (a / xp.where(own == 0, xp.ones_like(own), own) - 1.0)  # the model's own turn, scaled
    added = a * ts.smoothstep((t - ts.const(t, TURN_SPAN[0])) / ts.const(t, TURN_SPAN[1] - TURN_SPAN[0])) - face
    turn = xp.where(xp.abs(ts.degrees(own)) >= ts.const(own, MIN_MODEL_TURN), scaled, added)
    back = a * ts.smoothstep((u - ts.const(u, BACK_SPAN[0])) / ts.const(u, BACK_SPAN[1] - BACK_SPAN[0]))
    legs = xp.clip(1.5 * xp.sin(ts.const(u, math.pi * ZIGZAG_LEGS) * xp.minimum(u / ts.const(u, ZIGZAG_END), 1.0)),
                   -1.0, 1.0)
    zigzag = ts.const(u, math.radians(ZIGZAG_DEGREES)) * legs
    k = kind[:, None]
    target = xp.where(k == KINDS.index("back"), back, xp.where(k == KINDS.index("zigzag"), zigzag, a * u))
    drift = target - own * u  # the path's turning, less the model's own drift (its sway kept)
    return xp.where(k == KINDS.index("turn"), turn, xp.where(k == KINDS.index("strafe"), -face, drift))


def bend_features(features, kind, angle, fps: float, *, finite_check: bool = True):
    """Raw features (B, T, D) whose facing follows paths of ``kind`` (B,) (indices into KINDS) and ``angle`` (B,)
    radians: the heading offset of :func:`heading_offset`, the root's path pivoted about the planted foot
    (:func:`pivoted_path`). Array API, loop-free: the graph ``bend.onnx`` is this function (``finite_check``
    False: its caller checks the values)."""
    xp = namespace(features)
    extra = heading_offset(kind, angle, features)
    path = pivoted_path(features, extra, fps, finite_check=finite_check)
    turn = xp.concat([(extra[:, 1:] - extra[:, :-1]) / 2.0, xp.zeros_like(extra[:, :1])], axis=1)
    f = xp.concat([features[..., :1] - turn[..., None], features[..., 1:]], axis=-1)  # half-angles per frame
    return follow_path(f, path)


def bend(features: np.ndarray, spec: PathSpec | None) -> np.ndarray:
    """Raw features (T, D) whose facing follows ``spec`` (a copy; ``features`` itself when ``spec`` is None). The
    body turns about its planted foot where one is planted (the root's path moved so that the foot stays where it
    stands), else about the root (:func:`bend_features` of one motion)."""
    if spec is None or len(features) < 2:
        return features
    f = np.asarray(features, dtype=np.float64)[None]
    out = bend_features(f, np.array([KINDS.index(spec.kind)]), np.array([math.radians(spec.angle)]),
                        get_skeleton(SKELETON).fps)[0]
    return out.astype(np.asarray(features).dtype, copy=False)


def pivoted_path(features, extra, fps: float, *, finite_check: bool = True):
    """(B, T, 2) the root's XZ path of raw features (B, T, D) once the body is turned by ``extra`` (B, T) radians
    more at each frame: each step turned with its frame, and while a foot is planted in the original motion, the
    root moved about that foot so that the foot stays put (its position: the mean of the planted foot joints)."""
    xp = namespace(features)
    joints = joints_from_features(features, SKELETON, finite_check=finite_check)
    root = ts.xz(joints[:, :, 0])  # (B, T, 2)
    feet = xp.stack([joints[:, :, j] for j in HML_FOOT_JOINTS], axis=2)  # (B, T, 4, 3)
    planted = contacts_of_feet(feet, fps, CLEANUP_CONTACTS)  # (B, T, 4)
    c, s = xp.cos(extra), xp.sin(extra)

    def turn(k: slice, v):  # v (B, n, 2) turned about +Y by extra[:, k] (B, n)
        return xp.stack([c[:, k] * v[..., 0] + s[:, k] * v[..., 1], -s[:, k] * v[..., 0] + c[:, k] * v[..., 1]], -1)

    now, nxt = slice(0, -1), slice(1, None)
    both = planted[:, :-1] & planted[:, 1:]  # (B, T-1, 4): feet planted in frames t and t + 1
    count = xp.sum(xp.astype(both, features.dtype), axis=-1)[..., None]
    arm = xp.sum(ts.xz(feet[:, :-1]) * xp.astype(both, features.dtype)[..., None], axis=2) \
        / xp.maximum(count, xp.ones_like(count)) - root[:, :-1]  # (B, T-1, 2): root to that foot
    step = turn(nxt, root[:, 1:] - root[:, :-1]) + xp.where(count > 0, turn(now, arm) - turn(nxt, arm),
                                                            xp.zeros_like(arm))
    return xp.concat([xp.zeros_like(root[:, :1]), xp.cumulative_sum(step, axis=1)], axis=1)


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


def interp(x, xs, ys):
    """(B, S) values at ``x`` (B, S) of the piecewise-linear functions through (``xs``, ``ys``) (B, K), ``xs``
    increasing; the end values outside (numpy's ``interp``, per row, as array-API calls)."""
    xp = namespace(x)
    K = xs.shape[1]
    below = xp.sum(xp.astype(xs[:, None, :] <= x[:, :, None], xp.int64), axis=-1)  # (B, S) knots at or before x
    i = xp.clip(below - 1, 0, K - 2)
    x0, x1, y0, y1 = ts.at(xs, i), ts.at(xs, i + 1), ts.at(ys, i), ts.at(ys, i + 1)
    span = x1 - x0  # > 0 where xs increase; a row that does not is not read (follow_features' untimed rows)
    w = xp.clip((x - x0) / xp.where(span > 0, span, xp.ones_like(span)), 0.0, 1.0)
    return y0 + w * (y1 - y0)


def along(points, cum, s):
    """(B, S, 2) positions at arc lengths ``s`` (B, S) metres along polylines ``points`` (B, K, 2) whose arc lengths
    at the points are ``cum`` (B, K)."""
    xp = namespace(points)
    return xp.stack([interp(s, cum, points[..., 0]), interp(s, cum, points[..., 1])], axis=-1)


def follow_features(features, points, times, timed, fps: float, *, finite_check: bool = True):
    """Raw features (B, T, D) whose root runs along the polylines ``points`` (B, K, 2) metres (at the motion's own
    pace, or where ``timed`` (B,) at the ``times`` (B, K) seconds given) facing their direction, in the features'
    frame (the path turned so that it starts along the body's first facing); and how to place the result in the
    path's frame: the facing (B,) radians (positive to the left) and floor position (B, 2) of its first frame.
    Array API, loop-free: the graph ``follow.onnx`` is this function."""
    xp = namespace(features)
    step = ts.norm(points[:, 1:] - points[:, :-1])
    cum = xp.concat([xp.zeros_like(step[:, :1]), xp.cumulative_sum(step, axis=1)], axis=1)  # (B, K)
    clock = xp.astype(ts.frames(features), features.dtype)[None] / ts.const(features, fps)  # (1, T) seconds
    by_time = interp(clock + xp.zeros_like(features[..., 0]), times, cum)
    s = xp.where(timed[:, None], by_time, progress(features) * cum[:, -1:])
    p = along(points, cum, s)
    span = ts.const(s, TANGENT_SPAN)
    d = along(points, cum, s + span) - along(points, cum, s - span)
    heading = ts.unwrap(ts.atan2(d[..., 0], d[..., 1]))  # facing of +Z is 0, of +X (left) is +pi/2
    face = facing(features)
    start = heading[:, :1] - face[:, :1]  # the path turned by -start starts along the body's first facing
    c, sn = xp.cos(start), xp.sin(start)
    rel = p - p[:, :1]
    local = xp.stack([c * rel[..., 0] - sn * rel[..., 1], sn * rel[..., 0] + c * rel[..., 1]], axis=-1)
    extra = (heading - start) - face
    extra = extra - extra[:, :1]
    turn = xp.concat([(extra[:, 1:] - extra[:, :-1]) / 2.0, xp.zeros_like(extra[:, :1])], axis=1)
    f = xp.concat([features[..., :1] - turn[..., None], features[..., 1:]], axis=-1)
    return follow_path(f, local), start[:, 0], p[:, 0]


def follow_waypoints(features: np.ndarray, path: Waypoints, fps: float) -> tuple[np.ndarray, float, np.ndarray]:
    """Raw features (T, D) whose root runs along ``path`` (:func:`follow_features` of one motion); and how to place
    the result in the path's frame: the facing (radians, positive to the left) and the floor position (2,) of its
    first frame."""
    f = np.asarray(features, dtype=np.float64)[None]
    timed = path.times is not None
    times = path.times if timed else np.zeros(len(path.points))
    out, start, origin = follow_features(f, path.points[None], times[None], np.array([timed]), fps)
    return out[0], float(start[0]), origin[0].copy()


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
    from ..motion.root import place_rigid_like

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
    from ..motion.rigid import rigid_to_features

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


__all__ = ["PathSpec", "PromptPaths", "Waypoints", "KINDS", "bend", "bend_features", "follow", "follow_features", "facing", "interp", "along", "progress", "pivoted_path", "follow_waypoints", "place", "placed", "waypoints_for", "bend_segments", "heading_offset", "parse_path", "path_segments", "read_paths"]
