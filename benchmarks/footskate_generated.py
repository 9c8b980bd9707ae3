"""Foot skating of generated motions: off vs post vs loop cleanup, against real test motions.

For N test captions of a HumanML3D-layout corpus (evenly spaced over test.txt, each at its motion's
length), generates one motion per caption with the same seed in each mode and prints, as JSON, the mean
skate ratio, sliding speed and ground penetration per mode and for the real motions of those captions
(and of the whole test split), the mean joint change that cleanup causes (post vs off, after removing the
global heading/start the features leave free), seconds per motion for each mode, and, with --evaluator,
the FID of each mode against the real test motions.

    python benchmarks/footskate_generated.py [--checkpoint MODEL] [--teacher] --data /work/cache/bandai-corpus \
        --n 64 [--steps N] [--evaluator DIR]
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from stablemofusion.footskate import FootskateOptions
from stablemofusion.footskate.cleanup import align_yaw_xz, cleanup_features
from stablemofusion.footskate.metrics import joint_change, mean_metrics, pose_change
from stablemofusion.motion.features import joints_from_features
from stablemofusion.pipelines.motion_pipeline import MotionPipeline


def _captions(data: Path, ids: list[str]) -> list[str]:
    return [(data / "texts" / f"{i}.txt").read_text(encoding="utf-8").splitlines()[0].split("#")[0].strip()
            for i in ids]


def pick_test_items(pipe: MotionPipeline, data: Path, n: int,
                    split: str = "test") -> tuple[list[str], list[str], list[int]]:
    """``n`` motions of >= 40 frames, evenly spaced over SPLIT.txt: ids, first captions, lengths (frames)."""
    test_ids = [s for s in (data / f"{split}.txt").read_text().split() if s]
    usable = [i for i in test_ids if len(np.load(data / "new_joint_vecs" / f"{i}.npy", mmap_mode="r")) >= 40]
    ids = [usable[k] for k in np.linspace(0, len(usable) - 1, min(n, len(usable))).round().astype(int)]
    lengths = [pipe.frames_for(None, len(np.load(data / "new_joint_vecs" / f"{i}.npy", mmap_mode="r"))) for i in ids]
    return ids, _captions(data, ids), lengths


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", type=Path, default=None, help="model folder (default: the shipped model)")
    ap.add_argument("--teacher", action="store_true", help="the model's teacher instead (smf generate --teacher)")
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--n", type=int, default=64)
    ap.add_argument("--steps", type=int, default=None, help="sampling steps (default: the model's)")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--modes", default="off,post,loop")
    ap.add_argument("--loop-steps", type=int, default=2)
    ap.add_argument("--loop-skip-last", type=int, default=0)
    ap.add_argument("--evaluator", type=Path, default=None, help="evaluator folder for FID (smf train-evaluator)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    pipe = MotionPipeline.from_pretrained(args.checkpoint, teacher=args.teacher, device="cpu")
    ids, captions, lengths = pick_test_items(pipe, args.data, args.n)
    test_ids = [s for s in (args.data / "test.txt").read_text().split() if s]
    cleanup_features(np.load(args.data / "new_joint_vecs" / f"{ids[0]}.npy")[:40])  # pay torch.optim's import
    pipe.encode_text(captions)  # text embeddings cached: timings are the denoising and cleanup only
    pipe.sample(captions[:2], lengths[:2], steps=2, seed=0)  # warm-up: first forwards allocate
    options = FootskateOptions(loop_steps=args.loop_steps, loop_skip_last=args.loop_skip_last)
    feats: dict[str, list[np.ndarray]] = {}
    seconds: dict[str, float] = {}
    for mode in args.modes.split(","):
        out: list[np.ndarray] = []
        t = time.perf_counter()
        for a in range(0, len(ids), args.batch):
            sl = slice(a, a + args.batch)
            x = pipe.sample(captions[sl], lengths[sl], steps=args.steps, seed=args.seed + a, footskate=mode,
                            footskate_options=options)
            out += [x[j, :n].double().numpy() for j, n in enumerate(lengths[sl])]
        seconds[mode] = (time.perf_counter() - t) / len(ids)
        feats[mode] = out
    joints = {m: [joints_from_features(f) for f in fs] for m, fs in feats.items()}
    real = [np.load(args.data / "new_joints" / f"{i}.npy") for i in ids]
    real_all = [np.load(args.data / "new_joints" / f"{i}.npy") for i in test_ids]
    t = time.perf_counter()
    for f in feats.get("off", [])[:16]:
        cleanup_features(f)
    cleanup_s = (time.perf_counter() - t) / max(1, min(16, len(feats.get("off", []))))
    report = {
        "checkpoint": str(args.checkpoint), "teacher": args.teacher, "motions": len(ids),
        "steps": pipe.settings().steps if args.steps is None else args.steps,
        "guidance": pipe.settings().guidance_scale,
        "loop_steps": args.loop_steps, "loop_skip_last": args.loop_skip_last,
        "mean_frames": float(np.mean(lengths)),
        "metrics": {m: mean_metrics(j) for m, j in joints.items()},
        "real_same_captions": mean_metrics(real), "real_test_split": mean_metrics(real_all),
        "seconds_per_motion": seconds, "cleanup_only_seconds_per_motion": cleanup_s,
    }
    if "off" in joints:
        report["joint_change_m"] = {
            m: float(np.mean([joint_change(o, align_yaw_xz(c, o)) for o, c in zip(joints["off"], joints[m])]))
            for m in joints if m != "off"}
        report["pose_change_m"] = {  # the same without the change of the global path (root at the origin)
            m: float(np.mean([pose_change(o, c) for o, c in zip(joints["off"], joints[m])]))
            for m in joints if m != "off"}
    if args.evaluator is not None:
        from stablemofusion.eval.evaluator import load_evaluator
        from stablemofusion.eval.metrics import fid
        from stablemofusion.eval.protocol import EmbeddingModel

        ev, _ = load_evaluator(args.evaluator)
        emb = EmbeddingModel(ev, pipe.text_cache)
        ref = emb.motions([np.load(args.data / "new_joint_vecs" / f"{i}.npy") for i in test_ids])
        report["fid_vs_test_split"] = {m: fid(ref, emb.motions(fs)) for m, fs in feats.items()}
        report["fid_real_same_captions"] = fid(ref, emb.motions(
            [np.load(args.data / "new_joint_vecs" / f"{i}.npy") for i in ids]))
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
