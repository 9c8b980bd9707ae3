"""Atomic file output: a finished file is whole, a failed write leaves nothing, and the temporaries a killed writer
could not remove go on the next write of the same file."""

from __future__ import annotations

import os
import time

import pytest

from stablemofusion.core.io import STALE_TEMP_S, write_bytes, write_text


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "motion.bvh"
    write_text(target, "old")
    with pytest.raises(TypeError):
        write_bytes(target, "not bytes")  # type: ignore[arg-type]
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["motion.bvh"]


def test_a_killed_writers_old_temporaries_go_on_the_next_write(tmp_path):
    target = tmp_path / "a [1].gif"
    stale, fresh, other = tmp_path / ".a [1].gif.x1y2z3.gif", tmp_path / ".a [1].gif.q9w8e7.gif", tmp_path / ".b.gif.k.gif"
    for f in (stale, fresh, other):
        f.write_bytes(b"half")
    old = time.time() - STALE_TEMP_S - 60
    os.utime(stale, (old, old))
    os.utime(other, (old, old))
    write_bytes(target, b"GIF89a")
    # the old one of this target is gone; a recent one may be another writer's, and another target's is not ours
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([target.name, fresh.name, other.name])
