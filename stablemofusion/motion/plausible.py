"""The last check of every generated motion: one that no human makes is an error, never an answer.

A sampler pushed past what a model was trained for (a 1-step student asked for 50 steps) drifts into motions
whose root runs at hundreds of metres a second; they must not reach a file or an HTTP response. The rigid final
stage already makes every bone keep its length; this checks what it cannot: finite joints, a root no faster
than a sprinter, a body near the floor.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import SMFError

MAX_ROOT_SPEED = 12.0  # m/s, horizontal, over SPEED_WINDOW_S: faster than any human (sprinters peak near 12.4)
SPEED_WINDOW_S = 0.25  # the speed is measured over this span (a one-frame spike of the root is not a run)
MAX_HEIGHT = 5.0  # m: no joint higher above, or deeper below, the floor than this


class ImplausibleMotionError(SMFError):
    """A generated motion that no human makes (see :func:`check_plausible`)."""


def check_plausible(joints: np.ndarray, fps: float) -> None:
    """ImplausibleMotionError naming the first problem of ``joints`` (T, J, 3) metres, Y up, at ``fps``: a
    non-finite value, a horizontal root speed above MAX_ROOT_SPEED (m/s, over SPEED_WINDOW_S), or a joint more
    than MAX_HEIGHT from the floor."""
    joints = np.asarray(joints)
    if not np.isfinite(joints).all():
        raise ImplausibleMotionError("the generated motion has non-finite joints; try other settings (fewer steps)")
    height = float(np.abs(joints[..., 1]).max(initial=0.0))
    if height > MAX_HEIGHT:
        raise ImplausibleMotionError(f"the generated motion puts a joint {height:.1f} m from the floor (at most "
                                     f"{MAX_HEIGHT:g}); try other settings (fewer steps)")
    span = max(1, int(round(SPEED_WINDOW_S * fps)))
    if len(joints) > span:
        root = joints[:, 0, [0, 2]]
        speed = float((np.linalg.norm(root[span:] - root[:-span], axis=-1) * fps / span).max())
        if speed > MAX_ROOT_SPEED:
            raise ImplausibleMotionError(f"the generated motion's root moves at {speed:.1f} m/s (a human at most "
                                         f"{MAX_ROOT_SPEED:g}); try other settings (fewer steps)")
