"""Editing quality on real test-split motions: how exactly each mode keeps what it keeps, and the seams.

    python benchmarks/edit_quality.py --data CORPUS [--checkpoint MODEL] [--teacher] [--steps N] [--motions 12]
        [--impose x0 xt]

For each mode and way of imposing (x0 replacement, x_t imputation), over the first N test motions of at
least 120 frames (one prompt per motion, cycled from PROMPTS): the largest joint error at kept frames
(prefix, suffix, inbetween; cm), the largest lower-body joint error (upper-body mode; cm), the mean root
path error (trajectory; cm), and the largest joint acceleration at a seam (the accelerations that involve
both the last kept and the first generated frame of a boundary: frames b-2 .. b+1) against the 99th percentile and the maximum, over all frames and joints,
of the same motions' real accelerations (m/s^2). Final joints with the rigid stage, as users get them,
compared with the source passed through the same rigid stage (the source on the model's skeleton).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from stablemofusion.data.layout import MotionLayout
from stablemofusion.motion.features import joints_from_features
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

MODES = ("prefix", "suffix", "inbetween", "upper-body", "trajectory")
PROMPTS = ["a person jumps up and down", "someone walks in a circle", "a man crouches and stands up again",
           "a woman spins around", "a person kicks with the left leg", "someone waves both arms over the head"]


def accel(joints: np.ndarray, fps: float) -> np.ndarray:
    """(T, J, 3) -> (T-2,) largest joint acceleration per frame (m/s^2)."""
    a = (joints[2:] - 2 * joints[1:-1] + joints[:-2]) * fps ** 2
    return np.linalg.norm(a, axis=-1).max(-1)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--data", required=True)
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--teacher", action="store_true", help="the model's teacher instead (smf generate --teacher)")
    p.add_argument("--steps", type=int, default=None, help="sampling steps (default: the model's)")
    p.add_argument("--motions", type=int, default=12)
    p.add_argument("--impose", nargs="+", default=["x0", "xt"])
    p.add_argument("--seconds", type=float, default=1.5, help="kept seconds at each end")
    p.add_argument("--modes", nargs="+", default=list(MODES))
    a = p.parse_args()
    pipe = MotionPipeline.from_pretrained(a.checkpoint, teacher=a.teacher, device="cpu")
    layout = MotionLayout(a.data)
    sources = [f for f in (layout.load_features(i) for i in layout.ids("test")) if len(f) >= 120][:a.motions]
    fps, sk = pipe.fps, pipe.skeleton
    real_acc = np.concatenate([accel(joints_from_features(f, sk), fps) for f in sources])
    rows = []
    for impose in a.impose:
        for mode in a.modes:
            kept_err, seam_acc, t0 = [], [], time.perf_counter()
            for i, src in enumerate(sources):
                src = src[:pipe.max_frames].astype(np.float64)
                ks = a.seconds if mode in ("prefix", "inbetween") else 0.0
                ke = a.seconds if mode in ("suffix", "inbetween") else 0.0
                r = pipe.edit(PROMPTS[i % len(PROMPTS)], src, mode, keep_start=ks, keep_end=ke, seed=i, impose=impose,
                              steps=a.steps)
                ref, _ = pipe.finish(src)  # the source on the model's rigid skeleton, as the output is
                ref = joints_from_features(ref, sk)
                if mode == "upper-body":
                    kept_err.append(np.abs(r.joints[:, list(sk.lower_body)] - ref[:, list(sk.lower_body)]).max())
                elif mode == "trajectory":
                    kept_err.append(np.linalg.norm(r.joints[:, 0, [0, 2]] - ref[:len(r.joints), 0, [0, 2]], axis=-1).mean())
                else:
                    n_s, n_e, T = int(round(ks * fps)), int(round(ke * fps)), len(r.joints)
                    out_idx = list(range(n_s)) + list(range(T - n_e, T))
                    src_idx = list(range(n_s)) + list(range(len(src) - n_e, len(src)))
                    kept_err.append(np.abs(r.joints[out_idx] - ref[src_idx]).max())
                    acc = accel(r.joints, fps)
                    for b in ([n_s] if n_s else []) + ([T - n_e] if n_e else []):
                        seam_acc.append(acc[max(b - 2, 0):b].max())  # acc[t] spans frames t..t+2: b-2 .. b+1
            row = {"impose": impose, "mode": mode, "motions": len(sources),
                   "max_error_cm" if mode != "trajectory" else "mean_path_error_cm": float(np.max(kept_err) * 100)
                   if mode != "trajectory" else float(np.mean(kept_err) * 100),
                   "seconds_per_edit": (time.perf_counter() - t0) / len(sources)}
            if seam_acc:
                row.update(seam_acc_max=float(np.max(seam_acc)), seam_acc_median=float(np.median(seam_acc)))
            rows.append(row)
            print(json.dumps(row), flush=True)
    print(json.dumps({"real_acc_p99": float(np.percentile(real_acc, 99)), "real_acc_max": float(real_acc.max()),
                      "real_acc_median": float(np.median(real_acc)),
                      "guidance": pipe.settings(edit=True).guidance_scale}))


if __name__ == "__main__":
    main()
