"""Time and accuracy of the rigid final stage (fit + features written back) per 4 s motion, batch 1 and 32.

The shipped model's raw features for 32 prompts (80 frames, seeds 0..31, default sampler) go through
``TorchBackend.finish_many`` with each fit method; printed per method: ms per motion at batch 1 (mean over
the 32 motions, one call each) and at batch 32 (one call), the worst bone deviation from the dataset
skeleton (m), the mean joint change from the model's joints (m), the largest npy (float32) vs BVH
difference (m), and the largest difference between a motion fitted alone and in the batch of 32 (m).

    OMP_NUM_THREADS=1 python benchmarks/rigid_speed.py [--repeats 3] [--methods lbfgs,sweeps]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from stablemofusion.motion.features import bone_lengths, joints_from_features
from stablemofusion.motion.files import bvh_round_trip_error
from stablemofusion.motion.rigid import RigidFitConfig
from stablemofusion.motion.skeleton import HUMANML3D
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

PROMPTS = ["a person walks forward", "someone waves both hands", "a person runs in a circle", "a person jumps",
           "an old woman bows", "a child kicks", "a person raises the right hand", "a man sits down"]
BATCH, FRAMES = 32, 80


def timed(fn, repeats: int) -> float:
    """Best of ``repeats`` calls (seconds): the machine is shared, the minimum is the least disturbed."""
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def measure(pipe, raw: list[np.ndarray], config: RigidFitConfig, repeats: int) -> dict:
    pipe.rigid = config
    batch1 = sum(timed(lambda f=f: pipe.finish_many([f]), repeats) for f in raw) / len(raw)
    batch32 = timed(lambda: pipe.finish_many(raw), repeats) / len(raw)
    out = pipe.finish_many(raw)
    alone = [pipe.finish_many([f])[0][1].joints() for f in raw[:4]]
    target = np.asarray(HUMANML3D.bone_lengths)[1:]
    joints = [m.joints() for _, m in out]
    model = [joints_from_features(f) for f in raw]
    # the model's joints start at the XZ origin like the written-back body: compare them as they are
    return {"ms_per_motion_batch1": round(batch1 * 1000, 2), "ms_per_motion_batch32": round(batch32 * 1000, 2),
            "worst_bone_deviation_m": float(max(np.abs(bone_lengths(j)[:, 1:] - target).max() for j in joints)),
            "mean_joint_change_m": float(np.mean([np.linalg.norm(j - x, axis=-1).mean()
                                                  for j, x in zip(joints, model)])),
            "npy_vs_bvh_m": float(max(bvh_round_trip_error(j, m) for j, (_, m) in zip(joints, out))),
            "alone_vs_batched_m": float(max(np.abs(a - j).max() for a, j in zip(alone, joints)))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--methods", default="lbfgs,sweeps")
    args = ap.parse_args()
    torch.set_num_threads(1)
    pipe = MotionPipeline.from_pretrained(device="cpu")
    prompts = [PROMPTS[i % len(PROMPTS)] for i in range(BATCH)]
    raw = pipe.denoise(prompts, [FRAMES] * BATCH, seed=list(range(BATCH)))
    raw = [r.numpy().astype(np.float64) for r in raw]
    report = {m: measure(pipe, raw, RigidFitConfig(method=m), args.repeats) for m in args.methods.split(",")}
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
