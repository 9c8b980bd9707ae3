"""Post-cleanup trade-off on the rigid body: skate ratio, pops, joint change and FID for the default cleanup and
for settings that each undo one of its design choices.

Generates one motion per caption of a split once (the model's raw features), fits each one rigid body (the
pipeline's final stage), then cleans the same bodies with each setting, so only the cleanup differs. FID is
against the whole test split. Prints JSON rows. Tune on ``--split val``; report on test.

    python benchmarks/footskate_tradeoff.py --checkpoint DIR --data /work/cache/bandai-corpus --n 256 \
        --split val --evaluator DIR [--vgrf-model vgrf22.safetensors]
"""

from __future__ import annotations

import argparse
import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from stablemofusion.footskate.cleanup import CleanupConfig, align_yaw_xz, cleanup_rigid
from stablemofusion.footskate.contacts import KinematicContactConfig
from stablemofusion.footskate.metrics import joint_change, mean_metrics, pop_frames, pose_change
from stablemofusion.motion.features import joints_from_features
from stablemofusion.motion.rigid import rigid_from_features, rigid_to_features
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

from footskate_generated import pick_test_items  # noqa: E402  (run from the repo root: benchmarks/ is on sys.path)

DEFAULT = CleanupConfig()
SETTINGS = {
    "default": DEFAULT,
    "no step between holds (lift 0)": replace(DEFAULT, lift=0.0),
    "no lean into turns (lean 0)": replace(DEFAULT, lean=0.0),
    "contacts split at 0.3 m": replace(DEFAULT, max_slide=0.3),
    "holds never spaced (catch_up 1000 m/s)": replace(DEFAULT, catch_up=1000.0),
    "toes at their own height (toes_on_floor False)": replace(DEFAULT, toes_on_floor=False),
    "detector's contact speeds 0.5/0.8 m/s": replace(DEFAULT, kinematic=KinematicContactConfig()),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", type=Path, default=None, help="default: the shipped model")
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--n", type=int, default=48)
    ap.add_argument("--steps", type=int, default=None, help="sampling steps (default: the model's)")
    ap.add_argument("--split", default="test", help="split whose captions are generated (tune on val)")
    ap.add_argument("--evaluator", type=Path, default=None)
    ap.add_argument("--vgrf-model", type=Path, default=None,
                    help="distilled vGRF model (smf footskate distil): adds the vGRF routes as rows")
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    pipe = MotionPipeline.from_pretrained(args.checkpoint, device="cpu")
    ids, captions, lengths = pick_test_items(pipe, args.data, args.n, args.split)
    test_ids = [s for s in (args.data / "test.txt").read_text().split() if s]
    raw = []
    for a in range(0, len(ids), 32):
        x = pipe.denoise(captions[a:a + 32], lengths[a:a + 32], steps=args.steps, seed=a)
        raw += [x[j, :n].double().numpy() for j, n in enumerate(lengths[a:a + 32])]
    bodies = [rigid_to_features(rigid_from_features(f), f) for f in raw]  # (body at the origin, features)
    emb = ref = None
    if args.evaluator is not None:
        from stablemofusion.eval.evaluator import load_evaluator
        from stablemofusion.eval.metrics import fid
        from stablemofusion.eval.protocol import EmbeddingModel

        emb = EmbeddingModel(load_evaluator(args.evaluator)[0], pipe.text_cache)
        ref = emb.motions([np.load(args.data / "new_joint_vecs" / f"{i}.npy") for i in test_ids])
    off = [b.joints() for b, _ in bodies]
    rows = [{"setting": "model's raw motion", **mean_metrics([joints_from_features(f) for f in raw]),
             **({"fid": fid(ref, emb.motions(raw))} if emb else {})},
            {"setting": "off (rigid stage only)", **mean_metrics(off),
             **({"fid": fid(ref, emb.motions([f for _, f in bodies]))} if emb else {})}]
    settings = {k: (v, None) for k, v in SETTINGS.items()}
    if args.vgrf_model is not None:
        from stablemofusion.footskate.vgrf import load_vgrf_model

        vgrf = load_vgrf_model(args.vgrf_model).eval()
        settings["vGRF contacts (distilled model)"] = (replace(DEFAULT, contacts="vgrf"), vgrf)
    for name, (cfg, model) in settings.items():
        clean = [rigid_to_features(cleanup_rigid(b, pipe.fps, cfg, vgrf_model=model).motion, f)
                 for (b, _), f in zip(bodies, raw)]
        joints = [m.joints() for m, _ in clean]
        pops = sum(int(pop_frames(j).any(-1).sum()) for j in joints) / (sum(len(j) for j in joints) / pipe.fps) * 10
        rows.append({"setting": name, **mean_metrics(joints), "pops_per_10s": pops,
                     "joint_change": float(np.mean([joint_change(o, align_yaw_xz(c, o)) for o, c in zip(off, joints)])),
                     "pose_change": float(np.mean([pose_change(o, c) for o, c in zip(off, joints)])),
                     **({"fid": fid(ref, emb.motions([f for _, f in clean]))} if emb else {})})
        print(json.dumps(rows[-1]), flush=True)
    real = mean_metrics([np.load(args.data / "new_joints" / f"{i}.npy") for i in ids])
    print(json.dumps({"checkpoint": str(args.checkpoint or "shipped"), "split": args.split, "motions": len(ids),
                      "real_same_items": real, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
