"""A 20 s three-prompt timeline, checked: does the label classifier recognise each segment,
and is any join's velocity jump larger than the largest frame-to-frame change inside the segments?

    python benchmarks/timeline_check.py --classifier CL [--seeds 5] [--checkpoint MODEL] [--teacher] [--steps N]

Timeline "walk forward:8; wave both hands:6; bow:6" (three actions of the corpus). For each seed: the
classifier's content label of each segment's frames (restricted to nothing: all 24 contents compete); the
largest change of any joint's velocity between consecutive frames at each join (frames join-2 .. join+1)
and inside the segments away from the joins (more than 5 frames from a join), in m/s per frame.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from stablemofusion.eval.classifier import load_classifier
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

SEGMENTS = [("a person walks forward", 8.0), ("a person waves both hands", 6.0), ("a person bows", 6.0)]
WANTED = ["walk", "wave-both-hands", "bow"]


def velocity_change(joints: np.ndarray, fps: float) -> np.ndarray:
    """(T, J, 3) -> (T-2,) largest change of a joint's velocity (m/s) from frame t+1 to t+2."""
    v = (joints[1:] - joints[:-1]) * fps
    return np.linalg.norm(v[1:] - v[:-1], axis=-1).max(-1)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--classifier", required=True)
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--teacher", action="store_true", help="the model's teacher instead (smf generate --teacher)")
    p.add_argument("--steps", type=int, default=None, help="sampling steps (default: the model's)")
    p.add_argument("--seeds", type=int, default=5)
    a = p.parse_args()
    pipe = MotionPipeline.from_pretrained(a.checkpoint, teacher=a.teacher, device="cpu")
    clf = load_classifier(a.classifier)
    fps = pipe.fps
    bounds = np.cumsum([0] + [int(round(s * fps)) for _, s in SEGMENTS])
    recognised, worst_ratio = 0, 0.0
    for seed in range(a.seeds):
        t0 = time.perf_counter()
        r = pipe.timeline(SEGMENTS, seed=seed, steps=a.steps)
        took = time.perf_counter() - t0
        labels = [c for c, _ in clf.predict([r.features[bounds[i]:bounds[i + 1]] for i in range(len(SEGMENTS))])]
        dv = velocity_change(r.joints, fps)
        joins = [int(b) for b in bounds[1:-1]]
        at_join = max(dv[j - 3:j + 1].max() for j in joins)  # dv[t] spans frames t..t+2
        near = np.zeros(len(dv), dtype=bool)
        for j in joins:
            near[max(j - 8, 0):j + 6] = True
        inside = dv[~near].max()
        ok = sum(lab == w for lab, w in zip(labels, WANTED))
        recognised += ok
        worst_ratio = max(worst_ratio, at_join / inside)
        print(json.dumps({"seed": seed, "frames": len(r.joints), "labels": labels, "recognised": ok,
                          "join_velocity_change": float(at_join), "inside_max_velocity_change": float(inside),
                          "seconds": took}), flush=True)
    print(json.dumps({"segments_recognised": f"{recognised}/{len(SEGMENTS) * a.seeds}",
                      "worst_join_over_inside": worst_ratio, "guidance": pipe.settings().guidance_scale}))


if __name__ == "__main__":
    main()
