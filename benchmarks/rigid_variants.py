"""What the rigid final stage changes, and why a variant costs FID: the protocol (1 replication, no
multimodality) with the pipeline's final stage swapped for each variant; prints one JSON row per variant and a
markdown table. Tune on --split val (docs/rigid.md).

    python benchmarks/rigid_variants.py --data CORPUS --evaluator EV --split val --items 256 [--variants a,b]
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from stablemofusion.eval.evaluator import load_evaluator
from stablemofusion.eval.protocol import EmbeddingModel, EvalConfig, evaluate
from stablemofusion.footskate.metrics import mean_metrics
from stablemofusion.motion.features import feature_slices, features_in_frames_of, joints_from_features
from stablemofusion.motion.rigid import RigidFitConfig, rigid_from_features, rigid_to_features
from stablemofusion.pipeline import MotionPipeline

ROT = feature_slices("humanml3d").rotations
Finish = Callable[[np.ndarray], tuple[np.ndarray, object | None]]


def rigid(cfg: RigidFitConfig) -> Finish:
    def finish(f: np.ndarray):
        motion, out = rigid_to_features(rigid_from_features(f, "humanml3d", cfg), f, cfg)
        return out, motion
    return finish


def rotations_by_ik(f: np.ndarray):
    """No rigid stage; only the rotation channels replaced by inverse kinematics of the model's positions."""
    out = f.copy()
    out[:, ROT] = features_in_frames_of(joints_from_features(f), f, rotations="ik")[:, ROT]
    return out, None


def velocities_from_positions(f: np.ndarray):
    """No rigid stage; only the velocity channels recomputed from the model's positions."""
    return features_in_frames_of(joints_from_features(f), f, rotations="keep"), None


VARIANTS: dict[str, Finish] = {
    "model's raw motion (no rigid stage)": lambda f: (f, None),
    "rigid (default: dataset lengths, start from positions, 20 steps, rotations kept)": rigid(RigidFitConfig()),
    "rigid, rotation channels by IK of the rigid body": rigid(RigidFitConfig(rotations="ik")),
    "rigid, median bone lengths": rigid(RigidFitConfig(bone_lengths="median")),
    "rigid, start from the rotation channels": rigid(RigidFitConfig(start="rotations")),
    "rigid, closed form from the positions (no L-BFGS)": rigid(RigidFitConfig(iterations=0)),
    "rigid, closed form from the rotation channels": rigid(RigidFitConfig(iterations=0, start="rotations")),
    "no rigid; rotation channels by IK of the model's positions": rotations_by_ik,
    "no rigid; velocity channels from the model's positions": velocities_from_positions,
}
KEYS = ("fid", "top1", "top3", "skate_ratio", "slide_speed", "bone_worst", "npy_bvh_max", "model_change")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--evaluator", type=Path, required=True)
    ap.add_argument("--checkpoint", type=Path, default=None, help="default: the shipped model")
    ap.add_argument("--split", default="val")
    ap.add_argument("--items", type=int, default=256)
    ap.add_argument("--variants", default=None, help="comma list of variant numbers (0-based; default all)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    pipe = MotionPipeline.from_pretrained(args.checkpoint, device="cpu")
    emb = EmbeddingModel(load_evaluator(args.evaluator)[0], pipe.text_cache)
    names = list(VARIANTS)
    chosen = names if args.variants is None else [names[int(i)] for i in args.variants.split(",")]
    cfg = EvalConfig(replications=1, mm_captions=0, max_items=args.items, split=args.split)
    rows = []
    for name in chosen:
        pipe.finish = lambda f, footskate="off", options=None, fn=VARIANTS[name]: fn(np.asarray(f, np.float64))
        res = evaluate(pipe, emb, args.data, cfg, progress=False, skate_metrics=lambda j: mean_metrics(j), body=True)
        row = {"variant": name, "aits_ms": round(res["aits_seconds"] * 1000, 1),
               **{k: round(v[0], 4) for k, v in res["rows"]["Generated"].items()}}
        rows.append(row)
        print(json.dumps(row), flush=True)
    real = {k: round(v[0], 4) for k, v in res["rows"]["Real motion"].items()}
    print(json.dumps({"variant": "real motion", **real}))
    print("\n| variant | " + " | ".join(KEYS) + " | AITS (ms) |\n|---|" + "---|" * (len(KEYS) + 1))
    for r in rows + [{"variant": "real motion", **real}]:
        print(f"| {r['variant']} | " + " | ".join(f"{r[k]:.3f}" if k in r else "–" for k in KEYS)
              + f" | {r.get('aits_ms', '–')} |")


if __name__ == "__main__":
    main()
