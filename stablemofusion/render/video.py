"""Stick-figure rendering of joint positions to .mp4 / .gif clips and .png stills.

Joints are (T, J, 3) world positions in metres, Y up (HumanML3D convention). Frames are drawn with a
fixed perspective camera with Pillow (twice the size, then reduced: antialiased), the title drawn once per clip,
and streamed to the encoder (ffmpeg for .mp4; for .gif Pillow needs every frame before writing, so frames are
kept palettised at one byte per pixel).
"""

from __future__ import annotations

import math
import os
import textwrap
from pathlib import Path
from typing import Iterator

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..core.errors import SMFError
from ..core.io import atomic_path
from ..motion.skeleton import Skeleton, get_skeleton
from .encoders import check_encoder

__all__ = ["render_video", "render_frame", "render_strip", "VIDEO_SUFFIXES"]

VIDEO_SUFFIXES = (".mp4", ".gif")

_RIGHT, _LEFT, _SPINE = "#d9480f", "#1c7ed6", "#343a40"  # chains 0/3, 1/4, 2
_PATH = "#2b8a3e"
_BACKGROUND = "#ffffff"
_ELEVATION = math.radians(22.0)
_AZIMUTH = math.radians(35.0)  # from the +Z front, towards the character's left (+X)
_FOV = math.radians(34.0)
NEAR = 0.05  # body heights: the root path is drawn only where it lies further than this in front of the camera
FOLLOW_EXTENT = 4.0  # root paths longer than this many body heights: the camera follows the character
FOLLOW_SMOOTH = 1.0  # seconds over which the followed root position is averaged (no camera shake)
TITLE_CHARS, TITLE_LINES = 52, 4  # a title wraps at TITLE_CHARS characters, up to TITLE_LINES lines
POINT = 100.0 / 72.0  # pixels per point: sizes are in points at 100 dots per inch, as the drawings were designed
SUPERSAMPLE = 2  # frames are drawn at twice the size and reduced: antialiased lines


def _validate(joints: np.ndarray, sk: Skeleton) -> np.ndarray:
    """Return ``joints`` as a (T, J, 3) float64 array or raise SMFError."""
    arr = np.asarray(joints)
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise SMFError(f"joints must be a real numeric array, got dtype {arr.dtype}")
    if arr.ndim != 3 or arr.shape[1:] != (sk.num_joints, 3):
        raise SMFError(f"expected joints of shape (T, {sk.num_joints}, 3), got {tuple(arr.shape)}")
    if arr.shape[0] < 1:
        raise SMFError("joints have no frames (T=0)")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise SMFError("joints contain NaN or inf")
    return arr


def _check_size(size: int) -> int:
    """Validate the frame side in pixels and round it up to an even number (H.264 / yuv420p)."""
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 64 <= size <= 4096:
        raise SMFError(f"size must be an integer between 64 and 4096 pixels, got {size!r}")
    return int(size) + int(size) % 2


class _Camera:
    """Fixed pinhole camera looking at ``target`` from azimuth/elevation at ``distance`` (metres)."""

    def __init__(self, target: np.ndarray, azimuth: float, elevation: float, distance: float) -> None:
        back = np.array([math.sin(azimuth) * math.cos(elevation), math.sin(elevation),
                         math.cos(azimuth) * math.cos(elevation)])
        self.eye = target + distance * back
        fwd = -back
        right = np.cross(fwd, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        self.rot = np.stack([right, np.cross(right, fwd), fwd])  # rows: screen x, screen y, depth

    def project(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(..., 3) world points -> ((..., 2) image-plane coords, (...) depth in metres)."""
        cam = (pts - self.eye) @ self.rot.T
        depth = cam[..., 2]
        return cam[..., :2] / np.maximum(depth, 1e-3)[..., None], depth


def _rgb(color: str) -> tuple[float, float, float]:
    """'#rrggbb' -> (r, g, b) in [0, 1]."""
    return tuple(int(color[i:i + 2], 16) / 255.0 for i in (1, 3, 5))


def _blend(color: str | tuple, alpha: float) -> tuple[int, int, int]:
    """``color`` at opacity ``alpha`` over the white background, as 0-255 RGB."""
    rgb = _rgb(color) if isinstance(color, str) else color
    return tuple(int(round(255 * (1.0 - alpha * (1.0 - c)))) for c in rgb)


class _Scene:
    """One clip's drawing: geometry and the title are prepared once (:meth:`__init__`), then :meth:`draw` renders
    a frame with Pillow, at SUPERSAMPLE times the size and reduced (antialiased lines)."""

    def __init__(self, joints: np.ndarray, sk: Skeleton, title: str | None, size: int, fps: float) -> None:
        self.joints, self.sk, self.fps, self.size = joints, sk, fps, size
        parents = sk.parents
        self.bones = np.array([(p, j) for j, p in enumerate(parents) if p >= 0])  # (B, 2)
        side = {j: 2 for j in range(sk.num_joints)}
        for ci, chain in enumerate(sk.chains):  # colour each bone by the chain that owns its child
            for j in chain[1:]:
                side[j] = {0: 0, 3: 0, 1: 1, 4: 1}.get(ci, 2)
        kind = np.array([side[j] for _, j in self.bones])
        self.bone_colors = [[_RIGHT, _LEFT, _SPINE][k] for k in kind]
        px = size / 480.0
        self.px = px
        self.bone_widths = np.where(kind == 2, 5.0, 3.4) * px  # points
        spine = sk.chains[2] if len(sk.chains) > 2 else sk.chains[0]
        self.head, self.neck = spine[-1], spine[-2]

        # Body scale (~1.7 for a metre-scaled adult): leg chain + spine chain length, so sizes adapt.
        body = [np.linalg.norm(np.diff(joints[:, list(c)], axis=1), axis=-1).sum(-1) for c in (sk.chains[0], spine)]
        scale = float(np.median(body[0] + body[1])) / 1.7
        self.scale = scale if scale > 1e-6 else 1.0
        self.floor = float(joints[..., 1].min())
        self.root = joints[:, 0].copy()
        self.root[:, 1] = self.floor
        self.track = self._follow_track()  # (T, 3) per-frame camera offset (zeros: a fixed camera)
        self.offset = np.zeros(3)
        self.cam = self._make_camera()

        # the title band on top (wrapped per timeline segment), the drawing area below it
        lines = [ln for part in title.strip().split("; ") for ln in textwrap.wrap(part, width=TITLE_CHARS)] if title else []
        if len(lines) > TITLE_LINES:
            lines = lines[:TITLE_LINES]
            lines[-1] = lines[-1][: max(0, len(lines[-1]) - 1)].rstrip() + "\u2026"
        self.title_lines = lines
        font_px = 12.0 * px * POINT
        band = len(lines) * 1.35 * font_px + (14 if lines else 6) * px
        self.band = band / size  # share of the height above the drawing area
        self.limits = self._set_limits(aspect=(1.0 - self.band))
        s = SUPERSAMPLE
        self.base = Image.new("RGB", (size * s, size * s), _BACKGROUND)
        if lines:
            font = _font(font_px * s)
            draw = ImageDraw.Draw(self.base)
            y = 6 * px * s
            for line in lines:
                draw.text((size * s / 2, y), line, fill="#212529", font=font, anchor="ma")
                y += 1.3 * font_px * s
        self.clock_font = _font(9 * px * POINT * s)

    # -- camera ---------------------------------------------------------------------------------
    def _make_camera(self) -> _Camera:
        """One camera for the whole clip: 3/4 front view, or side-on to a long root trajectory."""
        pts = (self.joints - self.track[:, None]).reshape(-1, 3)
        lo, hi = pts.min(0), pts.max(0)
        lo[1] = self.floor
        target = (lo + hi) / 2
        azimuth = _AZIMUTH
        xz = self.root[:, [0, 2]] - self.root[:, [0, 2]].mean(0)
        if len(xz) > 1:
            _, sv, vt = np.linalg.svd(xz, full_matrices=False)
            if sv[0] / math.sqrt(len(xz)) > 0.6 * self.scale:  # travelling: look across the path
                dx, dz = vt[0]
                nx, nz = (-dz, dx) if dx > 0 or (dx == 0 and dz < 0) else (dz, -dx)
                azimuth = math.atan2(nx, nz) + math.radians(20.0)
        radius = max(0.5 * float(np.linalg.norm(hi - lo)), 0.9 * self.scale)
        return _Camera(target, azimuth, _ELEVATION, max(radius / math.sin(_FOV / 2), 3.0 * self.scale))

    def _follow_track(self) -> np.ndarray:
        """Where the camera looks from frame to frame: the root's floor position averaged over FOLLOW_SMOOTH
        seconds for a motion whose path spans more than FOLLOW_EXTENT body heights (so a long walk stays
        readable), else zeros (one fixed camera framing the whole path)."""
        xz = self.root[:, [0, 2]]
        track = np.zeros((len(xz), 3))
        if np.linalg.norm(xz.max(0) - xz.min(0)) <= FOLLOW_EXTENT * self.scale:
            return track
        k = max(1, int(round(FOLLOW_SMOOTH * self.fps)))
        padded = np.concatenate([np.repeat(xz[:1], k, 0), xz, np.repeat(xz[-1:], k, 0)])
        kernel = np.ones(2 * k + 1) / (2 * k + 1)
        track[:, [0, 2]] = np.stack([np.convolve(padded[:, i], kernel, "valid") for i in (0, 1)], 1)
        return track

    @property
    def follows(self) -> bool:
        return bool(self.track.any())

    def _project(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.cam.project(pts - self.offset)

    def _proj(self, pts: np.ndarray) -> np.ndarray:
        return self._project(pts)[0]

    def _set_limits(self, aspect: float) -> tuple[np.ndarray, np.ndarray]:
        """The image-plane box (lo, hi) that fits every frame's joints plus the root path on the floor, widened to
        the drawing area's shape (width / height = 1 / ``aspect``): equal scale on both screen axes."""
        rel = self.joints - self.track[:, None]
        xy = self._proj(np.concatenate([rel.reshape(-1, 3), (self.root - self.track) if self.follows else self.root]))
        lo, hi = xy.min(0), xy.max(0)
        pad = 0.08 * (hi - lo).max() + 0.02
        lo, hi = lo - pad, hi + pad
        w, h = hi - lo
        if w * aspect < h:
            lo[0], hi[0] = lo[0] - (h / aspect - w) / 2, hi[0] + (h / aspect - w) / 2
        else:
            lo[1], hi[1] = lo[1] - (w * aspect - h) / 2, hi[1] + (w * aspect - h) / 2
        return lo, hi

    def _pixels(self, xy: np.ndarray) -> np.ndarray:
        """Image-plane coordinates (..., 2) -> pixels of the supersampled frame (..., 2), y down."""
        lo, hi = self.limits
        full = self.size * SUPERSAMPLE
        top = self.band * full
        x = (xy[..., 0] - lo[0]) / (hi[0] - lo[0]) * full
        y = top + (hi[1] - xy[..., 1]) / (hi[1] - lo[1]) * (full - top)
        return np.stack([x, y], -1)

    # -- per frame ------------------------------------------------------------------------------
    def _grid(self, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-aligned floor grid around ``center`` (x, z), fading with distance: (segments (S, 2, 2) in the
        image plane, opacity (S,))."""
        step, reach = 0.5 * self.scale, 2.25 * self.scale
        ticks = np.arange(-reach, reach + 1e-9, step)
        base = np.round(center / step) * step
        sub = np.linspace(-reach, reach, 19)
        segs = []
        for axis in (0, 1):
            for t in ticks:
                line = np.zeros((len(sub), 3))
                line[:, 1] = self.floor
                line[:, [0, 2][axis]] = base[axis] + t
                line[:, [2, 0][axis]] = base[1 - axis] + sub
                segs.append(np.stack([line[:-1], line[1:]], 1))
        seg = np.concatenate(segs)  # (S, 2, 3)
        mid = seg.mean(1)[:, [0, 2]]
        fade = np.clip(1.0 - np.linalg.norm(mid - center, axis=-1) / reach, 0.0, 1.0) ** 1.5
        xy, depth = self._project(seg)
        keep = (depth > 0.05 * self.scale).all(1) & (fade > 0)
        return xy[keep], 0.75 * fade[keep]

    def draw(self, t: int) -> np.ndarray:
        """Render frame ``t``; return an (H, W, 3) uint8 RGB image."""
        s, px = SUPERSAMPLE, self.px
        width = (lambda points: max(1, int(round(points * POINT * s))))  # noqa: E731  (points -> pixels)
        pose = self.joints[t]
        if self.follows:
            self.offset = self.track[t]
        image = self.base.copy()
        d = ImageDraw.Draw(image)
        gxy, alpha = self._grid(pose[0, [0, 2]])
        for (a, b), al in zip(self._pixels(gxy), alpha):
            d.line([tuple(a), tuple(b)], fill=_blend((0.55, 0.55, 0.55), al), width=width(0.9 * px))
        # the root path on the floor, only what the picture shows of it: a follow camera sees long paths at a
        # grazing angle, and the whole path projected runs to millions of pixels
        path_xy, path_depth = self._project(self.root)
        path = self._pixels(path_xy)
        near = path_depth > NEAR * self.scale
        full = self.size * s
        box = (np.full(2, -0.1 * full), np.full(2, 1.1 * full))
        _dashed(d, path, _blend("#adb5bd", 1.0), width(1.2 * px), 6 * px * s, near, box)
        lw = width(2.0 * px)
        for a, b in _visible_segments(path[: t + 1], near[: t + 1], box):
            _segment(d, a, b, _PATH, lw)
        seg3 = pose[self.bones]  # (B, 2, 3)
        flat = seg3.copy()
        flat[..., 1] = self.floor
        shadow = _blend("#000000", 0.1)
        for (a, b), w in zip(self._pixels(self._proj(flat)), self.bone_widths * 1.4):
            _segment(d, a, b, shadow, width(w))
        xy, depth = self._project(seg3)
        pix = self._pixels(xy)
        order = np.argsort(-depth.mean(1))  # far bones first
        neck, head = pose[self.neck], pose[self.head]
        up = head - neck
        up /= max(np.linalg.norm(up), 1e-9)
        hxy, hd = self._project(head + 0.035 * self.scale * up)
        centre = self._pixels(hxy)
        lo, hi = self.limits
        radius = 0.085 * self.scale / hd / (hi[1] - lo[1]) * (self.size * s) * (1.0 - self.band)
        in_front = depth.mean(1)[order] < hd
        for i in order[~in_front]:
            _segment(d, pix[i, 0], pix[i, 1], self.bone_colors[i], width(self.bone_widths[i]))
        r, lw = float(radius), width(2.2 * px)
        d.ellipse([centre[0] - r, centre[1] - r, centre[0] + r, centre[1] + r], fill="#f1f3f5", outline=_SPINE,
                  width=lw)
        for i in order[in_front]:
            _segment(d, pix[i, 0], pix[i, 1], self.bone_colors[i], width(self.bone_widths[i]))
        n = len(self.joints)
        full = self.size * s
        y = full - 1.5 * s  # a thin timeline along the bottom edge (also keeps GIF frames distinct)
        d.line([(0, y), ((t + 1) / n * full, y)], fill=_PATH, width=width(3.0 * px))
        d.text((full - 8 * px * s, full - 8 * px * s), f"{t / self.fps:5.2f} s  {t + 1}/{n}", fill="#868e96",
               font=self.clock_font, anchor="rd")
        frame = image.resize((self.size, self.size), Image.Resampling.LANCZOS)
        return np.asarray(frame, dtype=np.uint8)

    def frames(self) -> Iterator[np.ndarray]:
        for t in range(len(self.joints)):
            yield self.draw(t)


def _font(pixels: float):
    """Pillow's own scalable font at ``pixels`` height (its bitmap font where FreeType is missing)."""
    try:
        return ImageFont.load_default(size=max(1, int(round(pixels))))
    except (TypeError, ImportError, OSError):  # Pillow < 10.1 or without FreeType
        return ImageFont.load_default()


def _segment(d: ImageDraw.ImageDraw, a, b, color, width: int) -> None:
    """A line with round caps."""
    d.line([tuple(a), tuple(b)], fill=color, width=width)
    r = width / 2
    for x, y in (a, b):
        d.ellipse([x - r, y - r, x + r, y + r], fill=color)


def _clipped(a: np.ndarray, b: np.ndarray, box: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, ...]:
    """Segments from ``a`` to ``b`` (S, 2) pixels clipped to ``box`` (lo, hi) (Liang-Barsky): (S,) whether any of
    each is inside, and the share (S,) along it where its inside part starts and stops."""
    lo, hi = box
    d = b - a
    t0, t1 = np.zeros(len(a)), np.ones(len(a))
    keep = np.ones(len(a), dtype=bool)
    for k in (0, 1):
        for p, q in ((-d[:, k], a[:, k] - lo[k]), (d[:, k], hi[k] - a[:, k])):
            flat = np.abs(p) < 1e-12
            keep &= ~(flat & (q < 0))
            r = q / np.where(flat, 1.0, p)
            t0 = np.where(~flat & (p < 0), np.maximum(t0, r), t0)
            t1 = np.where(~flat & (p > 0), np.minimum(t1, r), t1)
    return keep & (t0 < t1), t0, t1


def _visible_segments(pts: np.ndarray, near: np.ndarray, box) -> list[tuple[np.ndarray, np.ndarray]]:
    """The parts inside ``box`` of the segments of polyline ``pts`` (P, 2) whose two ends are in front of the camera
    (``near`` (P,))."""
    if len(pts) < 2:
        return []
    a, b = pts[:-1], pts[1:]
    keep, t0, t1 = _clipped(a, b, box)
    keep &= near[:-1] & near[1:]
    return [(a[i] + t0[i] * (b[i] - a[i]), a[i] + t1[i] * (b[i] - a[i])) for i in np.flatnonzero(keep)]


def _dashed(d: ImageDraw.ImageDraw, pts: np.ndarray, color, width: int, dash: float, near: np.ndarray, box) -> None:
    """A dashed polyline: ``dash`` pixels drawn, ``dash`` left out, along its length; only the segments in front of
    the camera (``near`` (P,)), and of them what lies in ``box`` (the dashes keep their places along the whole
    line), so its cost follows what is seen, not how long the line is."""
    if len(pts) < 2:
        return
    a, b = pts[:-1], pts[1:]
    steps = np.linalg.norm(b - a, axis=-1)
    along = np.concatenate([[0.0], np.cumsum(steps)])
    keep, t0, t1 = _clipped(a, b, box)
    keep &= near[:-1] & near[1:]
    for i in np.flatnonzero(keep & (steps > 0)):
        lo, hi = along[i] + t0[i] * steps[i], along[i] + t1[i] * steps[i]
        for start in np.arange(np.floor(lo / (2 * dash)) * 2 * dash, hi, 2 * dash):
            u0, u1 = max(start, lo), min(start + dash, hi)
            if u1 > u0:
                p0 = a[i] + (u0 - along[i]) / steps[i] * (b[i] - a[i])
                p1 = a[i] + (u1 - along[i]) / steps[i] * (b[i] - a[i])
                d.line([tuple(p0), tuple(p1)], fill=color, width=width)


def _scene(joints: np.ndarray, skeleton: str | Skeleton, title: str | None, size: int,
           fps: float | None) -> _Scene:
    sk = get_skeleton(skeleton)
    arr = _validate(joints, sk)
    fps = sk.fps if fps is None else float(fps)
    if not math.isfinite(fps) or fps <= 0:
        raise SMFError(f"fps must be a positive number, got {fps!r}")
    return _Scene(arr, sk, title, _check_size(size), fps)


def render_video(joints: np.ndarray, path: str | os.PathLike, *, skeleton: str | Skeleton = "humanml3d",
                 fps: float | None = None, title: str | None = None, size: int = 480) -> Path:
    """Render (T, J, 3) joints in metres (Y up) to ``path`` (.mp4 H.264/yuv420p or looping .gif).

    ``fps`` defaults to the skeleton's frame rate; frames are ``size`` x ``size`` pixels (rounded up to
    even). The file is written atomically; returns its path.
    """
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise SMFError(f"unsupported video format '{target.suffix}'; use .mp4 or .gif")
    check_encoder(suffix)
    scene = _scene(joints, skeleton, title, size, fps)
    with atomic_path(target) as tmp:
        if suffix == ".mp4":
            _write_mp4(scene.frames(), tmp, scene.fps)
        else:
            _write_gif(scene.frames(), tmp, scene.fps)
    return target


def write_frames(frames: Iterator[np.ndarray], path: str | os.PathLike, fps: float) -> Path:
    """(H, W, 3) uint8 RGB frames to ``path`` (.mp4 or .gif), atomically; returns its path."""
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise SMFError(f"unsupported video format '{target.suffix}'; use .mp4 or .gif")
    check_encoder(suffix)
    with atomic_path(target) as tmp:
        (_write_mp4 if suffix == ".mp4" else _write_gif)(frames, tmp, fps)
    return target


def _write_mp4(frames: Iterator[np.ndarray], path: Path, fps: float) -> None:
    """Stream RGB frames to H.264 via imageio's ffmpeg plugin (bundled imageio-ffmpeg binary)."""
    import imageio.v2 as imageio

    writer = imageio.get_writer(path, format="FFMPEG", mode="I", fps=fps, codec="libx264", quality=7,
                                pixelformat="yuv420p", macro_block_size=2, ffmpeg_log_level="error",
                                output_params=["-movflags", "+faststart"])
    with writer:
        for frame in frames:
            writer.append_data(frame)


def _gif_palette() -> Image.Image:
    """A fixed 255-colour palette: white-to-colour ramps of every drawing colour plus a grey ramp."""
    ramp = np.linspace(0.0, 1.0, 51)[:, None]
    rgb = [np.asarray(_rgb(c)) for c in (_RIGHT, _LEFT, _SPINE, _PATH, "#000000")]
    colors = np.concatenate([1.0 - ramp * (1.0 - c) for c in rgb])  # (255, 3)
    palette = Image.new("P", (1, 1))
    palette.putpalette(np.round(colors * 255).astype(np.uint8).ravel().tolist())
    return palette


def _write_gif(frames: Iterator[np.ndarray], path: Path, fps: float) -> None:
    """Write a looping GIF with Pillow; frames are palettised as they arrive (1 byte per pixel kept)."""
    palette = _gif_palette()
    images = [Image.fromarray(frame).quantize(palette=palette, dither=Image.Dither.NONE) for frame in frames]
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:], loop=0,
                   duration=max(20, round(1000.0 / fps)), disposal=1)


def render_frame(joints: np.ndarray, frame: int, path: str | os.PathLike, *,
                 skeleton: str | Skeleton = "humanml3d", title: str | None = None, size: int = 480) -> Path:
    """Render frame ``frame`` of (T, J, 3) joints in metres to a ``size`` x ``size`` PNG; returns its path."""
    scene = _scene(joints, skeleton, title, size, None)
    n = len(scene.joints)
    if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) or not 0 <= frame < n:
        raise SMFError(f"frame {frame!r} is out of range; valid frames are 0..{n - 1}")
    image = Image.fromarray(scene.draw(int(frame)))
    with atomic_path(path, suffix=".png") as tmp:
        image.save(tmp, format="PNG")
    return Path(path)


def render_strip(rows: list[tuple[str, np.ndarray]], frames: list[int], path: str | os.PathLike, *,
                 skeleton: str | Skeleton = "humanml3d", size: int = 240, window: int | None = None) -> Path:
    """A PNG grid: one row per (title, joints (T, J, 3)) motion, one ``size`` x ``size`` column per frame index
    of ``frames``, titled "<title>, frame N"; written atomically. Each row's camera frames the whole motion, or
    with ``window`` only the frames within ``window`` of the strip's (closer up on a long walk)."""
    if not rows or not frames:
        raise SMFError("a strip needs at least one motion and one frame")
    grid = []
    for title, joints in rows:
        n = len(_validate(joints, get_skeleton(skeleton)))
        bad = [f for f in frames if not 0 <= f < n]
        if bad:
            raise SMFError(f"frames {bad} are out of range for {title!r} (0..{n - 1})")
        lo, hi = (0, n) if window is None else (max(0, min(frames) - window), min(n, max(frames) + window + 1))
        grid.append(np.concatenate([_scene(joints[lo:hi], skeleton, f"{title}, frame {f}", size, None).draw(f - lo)
                                    for f in frames], axis=1))
    with atomic_path(path, suffix=".png") as tmp:
        Image.fromarray(np.concatenate(grid, axis=0)).save(tmp, format="PNG")
    return Path(path)
