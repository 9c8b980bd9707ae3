"""Footskate fixtures: the UnderPressure files in ../shared (skipped where absent) and a sliding motion."""

from __future__ import annotations

import numpy as np
import pytest

from pathlib import Path

UP = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "underpressure"


def need(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"shared data not found at {path} (only present in CI and developer checkouts)")
    return path


@pytest.fixture(scope="session")
def up_weights():
    return need(UP / "pretrained.tar")


@pytest.fixture(scope="session")
def s1(up_weights):
    from stablemofusion.footskate.underpressure import load_s1

    return load_s1(need(UP / "S1_Hopping.pth"))


@pytest.fixture(scope="session")
def wave() -> np.ndarray:
    """The packaged standing example (118, 22, 3)."""
    from stablemofusion.motion.files import load_motion

    return load_motion("example:wave-both-hands").joints


@pytest.fixture(scope="session")
def add_root_slide():
    return _add_root_slide


def _add_root_slide(joints: np.ndarray, amplitude: float = 0.06, fps: float = 20.0) -> np.ndarray:
    """Shift the whole body back and forth horizontally (feet that were planted now skate)."""
    t = np.arange(len(joints)) / fps
    out = joints.copy()
    out[..., 0] += (amplitude * np.sin(2 * np.pi * 1.3 * t))[:, None]
    out[..., 2] += (0.7 * amplitude * np.sin(2 * np.pi * 0.9 * t + 1.0))[:, None]
    return out
