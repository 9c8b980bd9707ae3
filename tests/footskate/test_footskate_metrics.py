"""Skate ratio, sliding speed, penetration and joint change on synthetic motions."""

import numpy as np
import pytest

from stablemofusion.core.errors import SMFError
from stablemofusion.footskate.metrics import (footskate_metrics, joint_change, penetration, pop_count, pop_frames,
                                             pose_change, skate_ratio, steps_after_stillness)


def _motion(T=21, slide=0.0, toe_h=0.0, low=0.0):
    j = np.zeros((T, 22, 3))
    j[:, :, 1] = 0.5
    j[:, [10, 11], 1] = toe_h
    j[:, [10, 11], 0] += (np.arange(T) * slide)[:, None]
    j[:, 0, 1] = low if low else 0.9
    return j


def test_static_feet_do_not_skate():
    m = footskate_metrics(_motion())
    assert m == {"skate_ratio": 0.0, "slide_speed": 0.0, "penetration": 0.0}


def test_sliding_feet_skate():
    j = _motion(slide=0.03)  # 3 cm per frame at 20 fps
    assert skate_ratio(j) == 1.0
    assert footskate_metrics(j)["slide_speed"] == pytest.approx(0.6)
    assert skate_ratio(_motion(slide=0.02)) == 0.0  # under 2.5 cm per frame
    assert skate_ratio(_motion(slide=0.03, toe_h=0.1)) == 0.0  # in the air


def test_other_fps_is_resampled_to_20():
    j = _motion(T=101, slide=0.006)  # 100 fps, 0.6 m/s
    assert footskate_metrics(j, fps=100.0)["skate_ratio"] == 1.0


def test_penetration_and_joint_change():
    j = _motion(low=-0.02)
    assert penetration(j) == pytest.approx(0.02)
    k = j.copy()
    k[..., 1] += 0.01
    assert joint_change(j, k) == pytest.approx(0.01)
    assert pose_change(j, k) == pytest.approx(0.0)  # a shift of the whole body is no pose change
    with pytest.raises(SMFError):
        joint_change(j, k[:-1])
    with pytest.raises(SMFError):
        footskate_metrics(np.zeros((5, 21, 3)))


def test_a_planted_foot_that_jumps_is_a_pop_and_a_steady_slide_is_not():
    j = _motion()
    j[10:, 10, 0] += 0.3  # the left toe, still on the floor, jumps 0.3 m between frames 9 and 10
    pops = pop_frames(j)
    assert pops.shape == (20, 4) and pops[:, 1].tolist() == [k == 9 for k in range(20)] and pops.sum() == 1
    assert pop_count(j) == 1 and 0.3 in np.round(steps_after_stillness(j), 6)
    assert pop_count(_motion(slide=0.2)) == 0  # fast all along: never still before the step
    lifted = j.copy()
    lifted[10:, 10, 1] = 0.2  # the same jump through the air: not a planted foot
    assert pop_count(lifted) == 0
