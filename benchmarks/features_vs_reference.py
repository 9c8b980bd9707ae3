"""Compare our features/joints with the HumanML3D reference files, group by group; print a table.

Usage: python benchmarks/features_vs_reference.py [../shared/data/humanml3d-reference]
"""

import sys
import time
from pathlib import Path

import numpy as np

from stablemofusion.motion.features import canonicalize, feature_slices, features_from_joints, joints_from_features

root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1].parent / "shared/data/humanml3d-reference")
print("| motion | check | max abs difference |\n|---|---|---|")
for path in sorted((root / "new_joints").glob("*.npy")):
    mid = path.stem
    joints = np.load(path)
    ref = np.load(root / "new_joint_vecs" / f"{mid}.npy")
    print(f"| {mid} | joints_from_features(reference features) vs new_joints (m) | {np.abs(joints_from_features(ref) - joints).max():.2e} |")
    t = time.perf_counter()
    feats = features_from_joints(joints)
    dt = time.perf_counter() - t
    back = joints_from_features(feats)
    print(f"| {mid} | round trip joints -> features -> joints (m) | {np.abs(back - canonicalize(joints)[:-1]).max():.2e} |")
    for name, sl in feature_slices().items():
        print(f"| {mid} | features '{name}' vs reference | {np.abs(feats[:, sl] - ref[:-1, sl]).max():.2e} |")
    print(f"| {mid} | features_from_joints time for {len(joints)} frames | {dt * 1000:.1f} ms |")
