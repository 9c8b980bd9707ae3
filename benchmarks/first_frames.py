"""Why the first frames of generated motions look worst (docs/rigid.md, "The first frames"). Prints JSON:

- ``bone_by_frame``: the model's raw joints, mean over test captions of the worst bone deviation per frame,
  against the motion's own median length and against the dataset skeleton (frames 0-9, mid-motion mean);
- ``yaw_snap``: how far the body (hip axis) turns between consecutive frames 0-1 ... 5-6, generated vs real;
- ``corpus_frame0_yaw``: the first yaw velocity of training motions, HumanML3D's convention vs "consistent";
- ``edge``: one-shot x0 predictions of noised real test motions, worst bone deviation at the first, middle
  and last frames (clip starts and crops starting at frame 12).

    python benchmarks/first_frames.py --data /work/cache/bandai-corpus [--checkpoint RUN] [--n 64]
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np
import torch

from stablemofusion.diffusion.schedulers import make_sampler
from stablemofusion.motion.features import bone_lengths, features_from_joints, joints_from_features
from stablemofusion.pipelines.motion_pipeline import MotionPipeline


def worst_bone(joints: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(T,) worst |bone length - reference| of each frame, metres."""
    return np.abs(bone_lengths(joints)[:, 1:] - reference[1:]).max(-1)


def hip_turn(joints: np.ndarray, n: int = 6) -> np.ndarray:
    """(n,) degrees the hip axis turns about +Y between frames k and k+1."""
    a = joints[: n + 1, 1] - joints[: n + 1, 2]
    yaw = np.degrees(np.arctan2(a[:, 2], a[:, 0]))
    return np.abs((np.diff(yaw) + 180) % 360 - 180)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--checkpoint", type=Path, default=None, help="default: the shipped model")
    ap.add_argument("--n", type=int, default=64)
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    pipe = MotionPipeline.from_pretrained(args.checkpoint, device="cpu")
    target = np.asarray(pipe.skeleton.bone_lengths)
    test = [i for i in (args.data / "test.txt").read_text().split() if not i.startswith("M")]
    ids = [i for i in test if len(np.load(args.data / "new_joint_vecs" / f"{i}.npy")) >= 60][: args.n]
    caps = [(args.data / "texts" / f"{i}.txt").read_text().split("\n")[0].split("#")[0] for i in ids]
    lens = [min(196, len(np.load(args.data / "new_joint_vecs" / f"{i}.npy")) // 4 * 4) for i in ids]
    raw = []
    for a in range(0, len(ids), 32):
        x = pipe.denoise(caps[a:a + 32], lens[a:a + 32], seed=a)
        raw += [joints_from_features(x[j, :n].double().numpy()) for j, n in enumerate(lens[a:a + 32])]
    real = [joints_from_features(np.load(args.data / "new_joint_vecs" / f"{i}.npy").astype(np.float64)) for i in ids]
    report = {"checkpoint": str(args.checkpoint or "shipped"), "motions": len(ids)}
    by = {}
    for name, ref in (("own_median", None), ("dataset_skeleton", target)):
        dev = [worst_bone(j, np.median(bone_lengths(j), 0) if ref is None else ref) for j in raw]
        by[name] = {"frames_0_9": [round(float(np.mean([d[k] for d in dev])), 4) for k in range(10)],
                    "mid": round(float(np.mean([d[20:-10].mean() for d in dev])), 4),
                    "last_3": [round(float(np.mean([d[-k] for d in dev])), 4) for k in (3, 2, 1)]}
    report["bone_by_frame"] = by
    g, r = np.array([hip_turn(j) for j in raw]), np.array([hip_turn(j) for j in real])
    report["yaw_snap"] = {"generated_mean": g.mean(0).round(2).tolist(), "generated_p95": np.percentile(g, 95, 0).round(1).tolist(),
                          "real_mean": r.mean(0).round(2).tolist(), "real_p95": np.percentile(r, 95, 0).round(1).tolist()}
    train = (args.data / "train.txt").read_text().split()[:300]
    f0 = {"official": [], "consistent": []}
    for i in train:
        j = np.load(args.data / "new_joints" / f"{i}.npy").astype(np.float64)
        for conv in f0:
            f0[conv].append(abs(features_from_joints(j, first_frame=conv)[0, 0]))
    report["corpus_frame0_yaw"] = {c: {"median": round(float(np.median(v)), 5), "p95": round(float(np.percentile(v, 95)), 5)}
                                   for c, v in f0.items()}
    report["corpus_later_yaw_median"] = round(float(np.median([abs(np.load(args.data / "new_joint_vecs" / f"{i}.npy")[5:-5, 0]).mean()
                                                               for i in train])), 5)
    # one-shot x0 predictions of noised real motions: edges vs middle
    long = [i for i in test if len(np.load(args.data / "new_joint_vecs" / f"{i}.npy")) >= 100][:48]
    tokens, tmask = pipe.encode_text([(args.data / "texts" / f"{i}.txt").read_text().split("#")[0] for i in long])
    ac = torch.as_tensor(make_sampler("ddpm", pipe.schedule).alphas_cumprod, dtype=torch.float32)
    edge = {}
    for name, start in (("clip_start", 0), ("crop_at_12", 12)):
        x0 = torch.stack([torch.as_tensor(np.load(args.data / "new_joint_vecs" / f"{i}.npy")[start:start + 80]) for i in long])
        x0 = (x0.float() - pipe.mean) / pipe.std
        for t in (100, 400, 950):
            noise = torch.randn(x0.shape, generator=torch.Generator().manual_seed(0))
            with torch.no_grad():
                pred = pipe.model(ac[t].sqrt() * x0 + (1 - ac[t]).sqrt() * noise, torch.full((len(long),), t), tokens,
                                  tmask, None, None)
            dev = np.array([worst_bone(joints_from_features(p.double().numpy()), target)
                            for p in pred * pipe.std + pipe.mean])
            edge[f"{name}_t{t}"] = {"first": round(float(dev[:, 0].mean()), 4), "mid": round(float(dev[:, 30:50].mean()), 4),
                                    "last": round(float(dev[:, -1].mean()), 4)}
    report["edge"] = edge
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
