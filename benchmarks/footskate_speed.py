"""Seconds per cleanup of one 196-frame motion (features in: the rigid fit, the cleanup, features out), one thread.

Real test motions of at least 150 frames, time-stretched to 196 frames, the first 20.

    python benchmarks/footskate_speed.py --data /work/cache/bandai-corpus [--vgrf-model FILE]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from stablemofusion.footskate.cleanup import CleanupConfig, cleanup_features
from stablemofusion.motion.features import features_from_joints
from stablemofusion.motion.resample import resample


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--vgrf-model", type=Path, default=None)
    ap.add_argument("--n", type=int, default=20)
    args = ap.parse_args()
    torch.set_num_threads(1)
    ids = [i for i in (args.data / "test.txt").read_text().split()
           if len(np.load(args.data / "new_joints" / f"{i}.npy", mmap_mode="r")) >= 150][:args.n]
    joints = [np.load(args.data / "new_joints" / f"{i}.npy") for i in ids]
    feats = [features_from_joints(resample(j, 20.0, 20.0 * 196 / (len(j) - 0.5))[:197]) for j in joints]
    cleanup_features(feats[0])  # warm
    runs = {"kinematic": {}, "kinematic, no lean": {"config": CleanupConfig(lean=0.0)}}
    if args.vgrf_model is not None:
        from stablemofusion.footskate.vgrf import load_vgrf_model

        model = load_vgrf_model(args.vgrf_model)
        runs["vgrf_contacts"] = {"vgrf_model": model, "config": CleanupConfig(contacts="vgrf")}
    out = {"motions": len(feats), "frames": int(feats[0].shape[0])}
    for name, kw in runs.items():
        t = time.perf_counter()
        for f in feats:
            cleanup_features(f, **kw)
        out[name] = (time.perf_counter() - t) / len(feats)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
