"""The last check of every generated motion: finite, a root no faster than a human, a body near the floor."""

from __future__ import annotations

import numpy as np
import pytest

from stablemofusion.motion.plausible import MAX_ROOT_SPEED, ImplausibleMotionError, check_plausible


def walk(speed: float, frames: int = 80, fps: float = 20.0) -> np.ndarray:
    """A 22-joint body 0.9 m high whose root moves forward at ``speed`` m/s."""
    j = np.zeros((frames, 22, 3))
    j[..., 1] = np.linspace(0.0, 1.7, 22)
    j[:, :, 2] += (np.arange(frames) * speed / fps)[:, None]
    return j


def test_a_human_motion_passes():
    check_plausible(walk(1.4), 20.0)  # a walk
    check_plausible(walk(9.0), 20.0)  # a sprint
    check_plausible(walk(0.0, frames=1), 20.0)  # one frame


@pytest.mark.parametrize("joints, words", [
    (walk(MAX_ROOT_SPEED * 1.5), "m/s"),
    (walk(1.0) + np.array([0.0, 40.0, 0.0]), "from the floor"),
    (np.where(np.arange(80)[:, None, None] == 7, np.nan, walk(1.0)), "non-finite"),
])
def test_what_no_human_does_is_an_error(joints, words):
    with pytest.raises(ImplausibleMotionError, match=words):
        check_plausible(joints, 20.0)


def test_a_one_frame_spike_of_the_root_is_not_a_run():
    j = walk(1.0)
    j[40, 0, 2] += 0.5  # one frame 0.5 m off: 10 m/s over a frame, 2 m/s over the 0.25 s window
    check_plausible(j, 20.0)
