"""Frame strips before/after the rigid final stage (docs/rigid.md): the README example and the stored
dragged-foot case, each as the model's own joints, the rigid stage, and the rigid stage + `--footskate post`;
prints the worst bone deviation of each row and the README example's right forearm lengths.

    python benchmarks/rigid_strips.py --out docs/img [--extra "old post cleanup=old_post_joints.npy"]
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np
import torch

from stablemofusion.footskate.cleanup import cleanup_features
from stablemofusion.motion.features import joints_from_features
from stablemofusion.motion.rigid import bone_length_deviation, rigid_from_features, rigid_to_features
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.render import render_strip

FIXTURE = Path(__file__).resolve().parents[1] / "tests" / "footskate" / "data" / "dragged_foot_features.npy"


def rows_for(features: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The model's joints, the rigid stage's and the rigid stage + post cleanup's, from raw features."""
    rigid, _ = rigid_to_features(rigid_from_features(features), features)
    _, post = cleanup_features(features)
    return [("model's joints", joints_from_features(features)), ("rigid stage", rigid.joints()),
            ("rigid + footskate post", post.joints())]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--extra", action="append", default=[], help="LABEL=JOINTS.npy: one more row for the dragged-foot strip")
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    pipe = MotionPipeline.from_pretrained(device="cpu")
    prompt = "a person waves both hands happily"
    raw = pipe.denoise([prompt], [80], seed=0)[0].double().numpy()
    drag = np.load(FIXTURE).astype(np.float64)
    extra = []
    for item in args.extra:
        label, file = item.split("=", 1)
        extra.append((label, np.load(file).astype(np.float64)))
    report = {}
    for name, feats, frames, more, window in (("readme_example", raw, [0, 3, 6, 30, 60], [], None),
                                              ("dragged_foot", drag, [146, 152, 158, 164, 170], extra, 12)):
        rows = rows_for(feats) + more
        report[name] = {title: round(bone_length_deviation(j)["bone_worst"], 4) for title, j in rows}
        render_strip(rows, frames, args.out / f"rigid_{name}.png", size=200, window=window)
    forearm = np.linalg.norm(joints_from_features(raw)[:, 21] - joints_from_features(raw)[:, 19], axis=-1)
    report["readme_example_right_forearm_m"] = {"frame_0": round(float(forearm[0]), 3),
                                                "median": round(float(np.median(forearm)), 3),
                                                "skeleton": round(float(pipe.skeleton.bone_lengths[21]), 3)}
    print(json.dumps({"prompt": prompt, "worst_bone_deviation_m": report}, indent=1))


if __name__ == "__main__":
    main()
