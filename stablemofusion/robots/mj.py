"""MuJoCo (the optional ``robot`` extra), imported once, with offscreen rendering through EGL where no display is
set (MuJoCo reads ``MUJOCO_GL`` on import); ``mujoco`` is None where it is not installed."""

from __future__ import annotations

import os
import sys

if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")
try:
    import mujoco
except ImportError:  # every entry point says how to install it (model.require_mujoco)
    mujoco = None

__all__ = ["mujoco"]
