"""Fixtures for motion tests: a few small real BVH files streamed out of the shared Bandai-Namco archive."""

from __future__ import annotations

import tarfile
from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
BANDAI_ARCHIVE = SHARED / "data" / "bandai-namco-motion.tar.xz"


@pytest.fixture(scope="session")
def bandai_bvh_files(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Paths to 3 small (< 250 kB) Bandai-Namco BVH files: the first ones met in the archive (dataset 1).

    The .xz stream is read sequentially and abandoned as soon as they are found, so this takes well
    under a second instead of unpacking 554 MB.
    """
    if not SHARED.is_dir():
        pytest.skip(f"shared data folder {SHARED} is absent")
    if not BANDAI_ARCHIVE.is_file():
        pytest.skip(f"{BANDAI_ARCHIVE} is absent")
    out = tmp_path_factory.mktemp("bandai")
    files: list[Path] = []
    with tarfile.open(BANDAI_ARCHIVE, "r|xz") as tar:
        for member in tar:
            if member.isfile() and member.name.endswith(".bvh") and member.size < 250_000:
                src = tar.extractfile(member)
                assert src is not None
                target = out / Path(member.name).name
                target.write_bytes(src.read())
                files.append(target)
                if len(files) == 3:
                    break
    if len(files) < 3:
        pytest.skip(f"{BANDAI_ARCHIVE} holds fewer than 3 small .bvh files")
    return files
