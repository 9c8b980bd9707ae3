"""What the rigid final stage changes, and why a variant costs FID: the protocol (1 replication, no
multimodality) with a pipeline whose final stage is each variant; prints one JSON row per variant and a
markdown table. Tune on --split val (docs/rigid.md).

    python benchmarks/rigid_variants.py --data CORPUS --evaluator EV --split val --items 256 [--variants a,b]
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import torch

from stablemofusion.eval.evaluator import load_evaluator
from stablemofusion.eval.protocol import EmbeddingModel, EvalConfig, evaluate
from stablemofusion.footskate.metrics import mean_metrics
from stablemofusion.motion.rigid import RigidFitConfig
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

VARIANTS: dict[str, RigidFitConfig | None] = {
    "model's raw motion (no rigid stage)": None,
    "rigid (default: dataset lengths, closed form + 4 block sweeps, rotations kept)": RigidFitConfig(),
    "rigid, L-BFGS from the closed form (20 steps; an earlier stage)": RigidFitConfig(method="lbfgs"),
    "rigid, rotation channels by IK of the rigid body": RigidFitConfig(rotations="ik"),
    "rigid, median bone lengths": RigidFitConfig(bone_lengths="median"),
    "rigid, start from the rotation channels": RigidFitConfig(start="rotations"),
    "rigid, closed form from the positions (no iterations)": RigidFitConfig(iterations=0),
    "rigid, closed form from the rotation channels": RigidFitConfig(iterations=0, start="rotations"),
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
    evaluator = load_evaluator(args.evaluator)[0]
    names = list(VARIANTS)
    chosen = names if args.variants is None else [names[int(i)] for i in args.variants.split(",")]
    cfg = EvalConfig(replications=1, mm_captions=0, max_items=args.items, split=args.split)
    rows = []
    for name in chosen:
        pipe = MotionPipeline.from_pretrained(args.checkpoint, device="cpu", rigid=VARIANTS[name])
        emb = EmbeddingModel(evaluator, pipe.text_cache)
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
