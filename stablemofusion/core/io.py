"""Atomic file output: write to a temporary file beside the target, then rename."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

import time

import numpy as np

STALE_TEMP_S = 3600.0  # a temporary of ours this old is a leftover of a killed writer (no writer takes an hour)


def remove_stale_temporaries(target: Path) -> list[Path]:
    """Remove the temporaries that writers of ``target`` killed without a chance to clean up (kill -9, power loss)
    left beside it: hidden ``.NAME.*`` files older than STALE_TEMP_S. Returns what was removed."""
    gone = []
    now = time.time()
    for f in target.parent.glob(f".{glob_escape(target.name)}.*"):
        try:
            if f.is_file() and not f.is_symlink() and now - f.stat().st_mtime > STALE_TEMP_S:
                f.unlink()
                gone.append(f)
        except OSError:  # gone meanwhile, or not ours to remove
            continue
    return gone


def glob_escape(name: str) -> str:
    """``name`` with glob's special characters taken literally."""
    return "".join(f"[{c}]" if c in "*?[" else c for c in name)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on error it is removed (and a
    killed writer's leftovers of the same target go on the next write: :func:`remove_stale_temporaries`).

    ``suffix`` defaults to the target's own suffix so writers that pick a format by extension work.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix if suffix is not None else target.suffix,
                               dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp makes 0600; give outputs the usual permissions
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def save_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    """Save ``array`` as ``.npy`` atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.save(f, np.asarray(array))


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; on success it replaces ``path`` (a whole folder), on error
    it is removed, so readers never see a half-written folder."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes 0700
    try:
        yield tmp
        for f in tmp.rglob("*"):  # some writers (safetensors) make 0600 files; give them the usual permissions
            if f.is_file() and not f.is_symlink():
                os.chmod(f, 0o666 & ~umask)
        old = target.with_name(f".{target.name}.old")
        if target.exists():
            os.replace(target, old)
        os.replace(tmp, target)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
