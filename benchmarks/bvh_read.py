"""Time reading + forward kinematics of every BVH file under a folder.

Usage: python benchmarks/bvh_read.py /path/to/unpacked/dataset
"""

import sys
import time
from pathlib import Path

from stablemofusion.motion.bvh import forward_kinematics, read_bvh

files = sorted(Path(sys.argv[1]).rglob("*.bvh"))
t0 = time.perf_counter()
frames = 0
for f in files:
    frames += len(forward_kinematics(read_bvh(f)))
dt = time.perf_counter() - t0
size = sum(f.stat().st_size for f in files) / 1e6
print(f"{len(files)} files, {size:.0f} MB, {frames} frames: read + FK in {dt:.1f} s ({size / dt:.0f} MB/s)")
