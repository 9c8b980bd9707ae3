"""Post-cleanup trade-off: skate ratio vs joint change vs FID for several weightings of the cleanup.

Generates one motion per test caption once (footskate off), then cleans the same motions with each
setting, so only the cleanup differs. Prints JSON rows.

    python benchmarks/footskate_tradeoff.py --checkpoint DIR --data /work/cache/bandai-corpus --n 48 \
        --evaluator DIR
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np
import torch

from stablemofusion.footskate.cleanup import CleanupConfig, align_yaw_xz, cleanup_features
from stablemofusion.footskate.contacts import KinematicContactConfig
from stablemofusion.footskate.metrics import joint_change, mean_metrics, pose_change
from stablemofusion.motion.features import joints_from_features
from stablemofusion.pipeline import MotionPipeline

from footskate_generated import pick_test_items  # noqa: E402  (run from the repo root: benchmarks/ is on sys.path)

SETTINGS = {
    "default": CleanupConfig(),
    "root x10": CleanupConfig(w_root=10.0),
    "root x100": CleanupConfig(w_root=100.0),
    "anchor /10": CleanupConfig(w_anchor=1.0),
    "strict contacts (0.5/0.8 m/s)": CleanupConfig(kinematic=KinematicContactConfig()),
    "strict contacts + root x10": CleanupConfig(w_root=10.0, kinematic=KinematicContactConfig()),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--n", type=int, default=48)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--evaluator", type=Path, default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    pipe = MotionPipeline.from_pretrained(args.checkpoint, device="cpu")
    ids, captions, lengths = pick_test_items(pipe, args.data, args.n)
    test_ids = [s for s in (args.data / "test.txt").read_text().split() if s]
    feats = []
    for a in range(0, len(ids), 16):
        x = pipe.sample(captions[a:a + 16], lengths[a:a + 16], steps=args.steps, seed=a)
        feats += [x[j, :n].double().numpy() for j, n in enumerate(lengths[a:a + 16])]
    emb = ref = None
    if args.evaluator is not None:
        from stablemofusion.eval.evaluator import load_evaluator
        from stablemofusion.eval.metrics import fid
        from stablemofusion.eval.protocol import EmbeddingModel

        emb = EmbeddingModel(load_evaluator(args.evaluator)[0], pipe.text_cache)
        ref = emb.motions([np.load(args.data / "new_joint_vecs" / f"{i}.npy") for i in test_ids])
    off = [joints_from_features(f) for f in feats]
    rows = [{"setting": "off", **mean_metrics(off), **({"fid": fid(ref, emb.motions(feats))} if emb else {})}]
    for name, cfg in SETTINGS.items():
        clean = [cleanup_features(f, cfg) for f in feats]
        joints = [joints_from_features(f) for f in clean]
        rows.append({"setting": name, **mean_metrics(joints),
                     "joint_change": float(np.mean([joint_change(o, align_yaw_xz(c, o)) for o, c in zip(off, joints)])),
                     "pose_change": float(np.mean([pose_change(o, c) for o, c in zip(off, joints)])),
                     **({"fid": fid(ref, emb.motions(clean))} if emb else {})})
    print(json.dumps({"checkpoint": str(args.checkpoint), "motions": len(ids), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
