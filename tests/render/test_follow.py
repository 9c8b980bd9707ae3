"""Long motions stay readable: the camera follows the character; long (timeline) titles wrap."""

import numpy as np

from stablemofusion.motion.files import load_motion
from stablemofusion.render.video import _scene


def _walk(seconds: float, speed: float = 1.4) -> np.ndarray:
    """The example pose sliding along +X at ``speed`` m/s for ``seconds`` (20 fps)."""
    pose = load_motion("example:wave-both-hands").joints[:1]
    t = np.arange(int(seconds * 20)) / 20
    return pose + np.stack([speed * t, 0 * t, 0 * t], 1)[:, None]


def _body_height_fraction(scene, t: int) -> float:
    scene.draw(t)
    xy = scene._proj(scene.joints[t])
    lo, hi = scene.limits
    return float((xy[:, 1].max() - xy[:, 1].min()) / (hi[1] - lo[1]))


def test_camera_follows_a_long_walk():
    long, short = _scene(_walk(60.0), "humanml3d", None, 240, 20.0), _scene(_walk(2.0), "humanml3d", None, 240, 20.0)
    assert long.follows and not short.follows
    assert _body_height_fraction(long, 600) > 0.25  # a full-path frame would make it a few percent
    assert _body_height_fraction(long, 600) > 0.5 * _body_height_fraction(short, 20)


def test_long_titles_wrap_per_segment():
    title = "; ".join(f"a person does thing number {i} slowly and carefully:3" for i in range(3))
    scene = _scene(_walk(1.0), "humanml3d", title, 240, 20.0)
    text = "\n".join(scene.title_lines)
    assert text.count("\n") >= 2 and "\u2026" not in text
