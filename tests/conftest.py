"""Shared fixtures: paths to the read-only ../shared data (absent on a user's fresh machine)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
HML_REF = SHARED / "humanml3d-reference"
BANDAI_ARCHIVE = SHARED / "bandai-namco-motion.tar.xz"


def need(path: Path) -> Path:
    """Skip the test with a clear reason when shared data is missing."""
    if not path.exists():
        pytest.skip(f"shared data not found at {path} (only present in CI and developer checkouts)")
    return path


@pytest.fixture(scope="session")
def hml_ref() -> Path:
    return need(HML_REF)


@pytest.fixture(scope="session", params=["000000", "012314"])
def ref_motion(request, hml_ref) -> tuple[str, np.ndarray, np.ndarray]:
    """(id, new_joints (T, 22, 3), new_joint_vecs (T, 263)) of a reference HumanML3D motion."""
    mid = request.param
    return mid, np.load(hml_ref / "new_joints" / f"{mid}.npy"), np.load(hml_ref / "new_joint_vecs" / f"{mid}.npy")
