"""Tests for stablemofusion.render.video: mp4/gif/png output, validation and atomic writes."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from PIL import Image

from stablemofusion.core.errors import SMFError
from stablemofusion.motion.skeleton import HUMANML3D
from stablemofusion.render import render_frame, render_video
from stablemofusion.render import video as video_mod

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
REFERENCE = SHARED / "data" / "humanml3d-reference" / "new_joints" / "000000.npy"


@pytest.fixture(scope="module")
def kick() -> np.ndarray:
    """(116, 22, 3) reference clip: a man kicking with his left leg."""
    if not REFERENCE.is_file():
        pytest.skip(f"reference data not found at {REFERENCE} (needs the sibling ../shared checkout)")
    return np.load(REFERENCE)


def rest_pose_clip(frames: int = 6) -> np.ndarray:
    """(frames, 22, 3) HumanML3D rest pose standing on the floor, drifting slowly along +Z."""
    offsets = HUMANML3D.target_offsets()
    pose = np.zeros((22, 3))
    for j, p in enumerate(HUMANML3D.parents):
        if p >= 0:
            pose[j] = pose[p] + offsets[j]
    pose[:, 1] -= pose[:, 1].min()
    clip = np.repeat(pose[None], frames, axis=0)
    clip[:, :, 2] += np.linspace(0.0, 0.1, frames)[:, None]
    return clip


def non_background(image: np.ndarray) -> int:
    return int((np.abs(image.astype(int) - 255).sum(-1) > 60).sum())


def test_mp4_reference(kick: np.ndarray, tmp_path: Path) -> None:
    out = render_video(kick, tmp_path / "kick.mp4", title="a man kicks something or someone with his left leg.")
    assert out == tmp_path / "kick.mp4"
    frames = iio.imread(out, plugin="FFMPEG")
    assert frames.shape == (116, 480, 480, 3)
    meta = iio.immeta(out, plugin="FFMPEG")
    assert meta["fps"] == pytest.approx(20.0) and meta["codec"] == "h264"
    assert "yuv420p" in meta["pix_fmt"]
    assert [p.name for p in tmp_path.iterdir()] == ["kick.mp4"]


def test_gif_reference(kick: np.ndarray, tmp_path: Path) -> None:
    out = render_video(kick[:40], tmp_path / "kick.gif", size=240)
    frames = iio.imread(out, index=None)
    assert frames.shape[:3] == (40, 240, 240)
    with Image.open(out) as im:
        assert im.info["loop"] == 0 and im.info["duration"] == 50
    assert non_background(frames[20]) > 1000


def test_png_reference(kick: np.ndarray, tmp_path: Path) -> None:
    out = render_frame(kick, 40, tmp_path / "still.png", title="kick")
    image = np.asarray(Image.open(out).convert("RGB"))
    assert image.shape == (480, 480, 3)
    assert non_background(image) > 5000
    r, g, b = (image[..., i].astype(int) for i in range(3))
    assert ((r - b) > 100).sum() > 200, "right limbs (orange) missing"
    assert ((b - r) > 100).sum() > 200, "left limbs (blue) missing"


def test_synthetic_png_and_odd_size(tmp_path: Path) -> None:
    out = render_frame(rest_pose_clip(), 0, tmp_path / "rest.png", size=131, title="x " * 200)
    image = np.asarray(Image.open(out).convert("RGB"))
    assert image.shape == (132, 132, 3)  # rounded up to even
    assert non_background(image) > 300


def test_synthetic_video_frame_count_and_fps(tmp_path: Path) -> None:
    clip = rest_pose_clip(7)
    mp4 = render_video(clip, tmp_path / "a.MP4", fps=10, size=128)
    assert iio.imread(mp4, plugin="FFMPEG").shape == (7, 128, 128, 3)
    assert iio.immeta(mp4, plugin="FFMPEG")["fps"] == pytest.approx(10.0)
    gif = render_video(clip, tmp_path / "a.gif", size=128)
    assert iio.imread(gif, index=None).shape[0] == 7


@pytest.mark.parametrize(
    ("joints", "message"),
    [
        (np.zeros((5, 4)), r"expected joints of shape \(T, 22, 3\), got \(5, 4\)"),
        (np.zeros((5, 21, 3)), r"expected joints of shape \(T, 22, 3\), got \(5, 21, 3\)"),
        (np.zeros((0, 22, 3)), "no frames"),
        (np.full((3, 22, 3), "a"), "numeric"),
    ],
)
def test_bad_input(joints: np.ndarray, message: str, tmp_path: Path) -> None:
    with pytest.raises(SMFError, match=message):
        render_video(joints, tmp_path / "x.mp4")
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite(bad: float, tmp_path: Path) -> None:
    clip = rest_pose_clip()
    clip[2, 5, 1] = bad
    with pytest.raises(SMFError, match="NaN or inf"):
        render_frame(clip, 0, tmp_path / "x.png")


def test_unsupported_suffix_and_options(tmp_path: Path) -> None:
    clip = rest_pose_clip()
    with pytest.raises(SMFError, match=r"unsupported video format '\.avi'; use \.mp4 or \.gif"):
        render_video(clip, tmp_path / "x.avi")
    with pytest.raises(SMFError, match=r"valid frames are 0\.\.5"):
        render_frame(clip, 6, tmp_path / "x.png")
    with pytest.raises(SMFError, match="fps"):
        render_video(clip, tmp_path / "x.mp4", fps=0)
    with pytest.raises(SMFError, match="size"):
        render_video(clip, tmp_path / "x.gif", size=8)
    with pytest.raises(SMFError, match="unknown skeleton"):
        render_video(clip, tmp_path / "x.gif", skeleton="nope")
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_failed_render_leaves_no_partial_file(suffix: str, tmp_path: Path, monkeypatch) -> None:
    draw = video_mod._Scene.draw

    def flaky(self, t: int) -> np.ndarray:
        if t == 3:
            raise RuntimeError("boom")
        return draw(self, t)

    monkeypatch.setattr(video_mod._Scene, "draw", flaky)
    target = tmp_path / f"clip{suffix}"
    with pytest.raises(RuntimeError, match="boom"):
        render_video(rest_pose_clip(), target, size=128)
    assert not any(tmp_path.iterdir())

    target.write_bytes(b"old")  # an existing file is left untouched by a failed render
    with pytest.raises(RuntimeError):
        render_video(rest_pose_clip(), target, size=128)
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == [target.name]


def test_strip_grid_of_motions_and_frames(tmp_path: Path) -> None:
    from stablemofusion.render import render_strip

    clip = rest_pose_clip(10)
    out = render_strip([("a", clip), ("b", clip + [0.0, 0.0, 0.5])], [0, 4, 9], tmp_path / "s.png", size=100,
                       window=2)
    image = np.asarray(Image.open(out).convert("RGB"))
    assert image.shape == (200, 300, 3)
    for r in range(2):
        for c in range(3):
            assert non_background(image[r * 100:(r + 1) * 100, c * 100:(c + 1) * 100]) > 100  # a figure in every cell
    with pytest.raises(SMFError, match="out of range"):
        render_strip([("a", clip)], [10], tmp_path / "t.png")
    assert not (tmp_path / "t.png").exists()


def test_mp4_without_ffmpeg_is_one_clear_error(tmp_path: Path, monkeypatch) -> None:
    import importlib.util

    from stablemofusion.core.output import parse_formats

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "imageio_ffmpeg" else real(name, *a))
    with pytest.raises(SMFError, match=r"stablemofusion\[video\]"):
        render_video(rest_pose_clip(), tmp_path / "x.mp4")
    with pytest.raises(SMFError, match=r"stablemofusion\[video\]"):
        parse_formats("npy,mp4")
    assert parse_formats("npy,gif") == ["npy", "gif"] and not any(tmp_path.iterdir())


class _CountingDraw:
    def __init__(self):
        self.lines = []

    def line(self, points, fill=None, width=1):
        self.lines.append(points)


def test_a_dashed_path_costs_what_the_picture_shows():
    """A root path that projects far outside the picture (a follow camera at a grazing angle): only the dashes inside
    the picture's box are drawn, at their places along the whole path; segments behind the camera are left out."""
    from stablemofusion.render.video import _dashed, _visible_segments

    box = (np.zeros(2), np.full(2, 1000.0))
    pts = np.array([[-1e7, 500.0], [1e7, 500.0], [1e7, 1e7]])  # 3e7 px long, 1000 px of it inside the box
    d = _CountingDraw()
    _dashed(d, pts, (0, 0, 0), 1, 10.0, np.ones(3, bool), box)
    assert 45 <= len(d.lines) <= 51  # 1000 px of 10 px dashes and 10 px gaps
    xs = np.array([[p[0] for p in line] for line in d.lines])
    assert xs.min() >= 0.0 and xs.max() <= 1000.0 and np.allclose(np.diff(xs[:, 0]), 20.0)
    d = _CountingDraw()
    _dashed(d, pts, (0, 0, 0), 1, 10.0, np.array([True, False, True]), box)  # the middle point behind the camera
    assert not d.lines
    seg = _visible_segments(np.array([[-500.0, 200.0], [500.0, 200.0], [600.0, 2000.0]]), np.ones(3, bool), box)
    assert len(seg) == 2 and np.allclose(seg[0], [[0.0, 200.0], [500.0, 200.0]])
