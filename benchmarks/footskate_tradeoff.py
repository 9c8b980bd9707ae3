"""Post-cleanup trade-off: skate ratio vs joint change vs FID for the default cleanup and for settings that
each undo one of its design choices.

Generates one motion per caption of a split once (footskate off), then cleans the same motions with each
setting, so only the cleanup differs. FID is against the whole test split. Prints JSON rows. Tune on
``--split val``; report on test.

    python benchmarks/footskate_tradeoff.py --checkpoint DIR --data /work/cache/bandai-corpus --n 256 \
        --split val --evaluator DIR [--vgrf-model vgrf22.safetensors]
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np
import torch

from stablemofusion.footskate.cleanup import (CleanupConfig, align_yaw_xz, cleanup_features, cleanup_joints,
                                              features_from_cleaned)
from stablemofusion.footskate.contacts import KinematicContactConfig
from stablemofusion.footskate.metrics import joint_change, mean_metrics, pose_change
from stablemofusion.motion.features import joints_from_features
from stablemofusion.pipeline import MotionPipeline

from footskate_generated import pick_test_items  # noqa: E402  (run from the repo root: benchmarks/ is on sys.path)


def _leg_bone_change(before: np.ndarray, after: np.ndarray) -> dict[str, float]:
    """Mean |change| (m) of the shin (knee-ankle) and foot (ankle-toe) lengths, frame by frame."""
    def length(j, a, b):
        return np.linalg.norm(j[:, a] - j[:, b], axis=-1)
    shin = [np.abs(length(after, c, p) - length(before, c, p)).mean() for c, p in ((7, 4), (8, 5))]
    foot = [np.abs(length(after, c, p) - length(before, c, p)).mean() for c, p in ((10, 7), (11, 8))]
    return {"shin_change": float(np.mean(shin)), "foot_change": float(np.mean(foot))}


def _recomputed(f: np.ndarray, cfg: CleanupConfig = CleanupConfig()) -> np.ndarray:
    """The default cleanup, but every feature recomputed from the cleaned joints (rotations by IK)."""
    return features_from_cleaned(cleanup_joints(joints_from_features(f), config=cfg).joints)


SETTINGS = {
    "default": lambda f: cleanup_features(f),
    "features recomputed from joints (no edit)": _recomputed,
    "root path free (w_root_offset 0)": lambda f: cleanup_features(f, CleanupConfig(w_root_offset=0.0)),
    "root path free + recomputed (session 2's cleanup, new anchors)":
        lambda f: _recomputed(f, CleanupConfig(w_root_offset=0.0)),
    "toes at their mean height (anchor_floor False)": lambda f: cleanup_features(f, CleanupConfig(anchor_floor=False)),
    "bone lengths kept harder (w_bone 100)": lambda f: cleanup_features(f, CleanupConfig(w_bone=100.0)),
    "anchor weight 10, 12 iterations": lambda f: cleanup_features(f, CleanupConfig(w_anchor=10.0, iterations=12)),
    "contact speeds 1.0/1.5 m/s": lambda f: cleanup_features(
        f, CleanupConfig(kinematic=KinematicContactConfig(speed_on=1.0, speed_off=1.5))),
    "detector's contact speeds 0.5/0.8 m/s": lambda f: cleanup_features(
        f, CleanupConfig(kinematic=KinematicContactConfig())),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--n", type=int, default=48)
    ap.add_argument("--steps", type=int, default=10)
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
    feats = []
    for a in range(0, len(ids), 32):
        x = pipe.sample(captions[a:a + 32], lengths[a:a + 32], steps=args.steps, seed=a)
        feats += [x[j, :n].double().numpy() for j, n in enumerate(lengths[a:a + 32])]
    emb = ref = None
    if args.evaluator is not None:
        from stablemofusion.eval.evaluator import load_evaluator
        from stablemofusion.eval.metrics import fid
        from stablemofusion.eval.protocol import EmbeddingModel

        emb = EmbeddingModel(load_evaluator(args.evaluator)[0], pipe.text_cache)
        ref = emb.motions([np.load(args.data / "new_joint_vecs" / f"{i}.npy") for i in test_ids])
    off = [joints_from_features(f) for f in feats]
    rows = [{"setting": "off", **mean_metrics(off), **({"fid": fid(ref, emb.motions(feats))} if emb else {})}]
    settings = dict(SETTINGS)
    if args.vgrf_model is not None:
        from stablemofusion.footskate.distil import load_vgrf_model

        vgrf = load_vgrf_model(args.vgrf_model).eval()
        settings["+ vGRF loss (distilled model)"] = lambda f: cleanup_features(f, vgrf_model=vgrf)
        settings["vGRF contacts + vGRF loss (distilled model)"] = lambda f: cleanup_features(
            f, CleanupConfig(contacts="vgrf"), vgrf_model=vgrf)
    for name, clean_fn in settings.items():
        clean = [clean_fn(f) for f in feats]
        joints = [joints_from_features(f) for f in clean]
        bones = [_leg_bone_change(o, c) for o, c in zip(off, joints)]
        rows.append({"setting": name, **mean_metrics(joints),
                     "joint_change": float(np.mean([joint_change(o, align_yaw_xz(c, o)) for o, c in zip(off, joints)])),
                     "pose_change": float(np.mean([pose_change(o, c) for o, c in zip(off, joints)])),
                     **{k: float(np.mean([b[k] for b in bones])) for k in ("shin_change", "foot_change")},
                     **({"fid": fid(ref, emb.motions(clean))} if emb else {})})
    real = mean_metrics([np.load(args.data / "new_joints" / f"{i}.npy") for i in ids])
    print(json.dumps({"checkpoint": str(args.checkpoint), "split": args.split, "motions": len(ids),
                      "real_same_items": real, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
