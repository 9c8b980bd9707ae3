"""How different the motions of one prompt are across seeds, against how different the corpus's own takes of the
same action and style are.

    python benchmarks/seed_variety.py --data CORPUS [--classifier CL] [--seeds 5] [--frames 64]

Per prompt of benchmarks/prompts_plain.jsonl (each names the corpus label it asks for: content and style, dataset
2, whose labels have many takes): ``--seeds`` motions at the model's length. Per label: its real takes (up to 12).
Every motion is put at the origin facing +Z at its first frame, resampled to ``--frames`` frames over its length,
and a set's variety is the mean over its pairs of the mean joint distance (m). The ratio generated / real per
label, of the whole motion and of the pose alone (joints relative to the root: the body without its path); the
table lists the prompts furthest below their label's variety. With ``--classifier``: how many of the motions the
motion classifier names with their label's content and style (dataset 2's labels), so that variety is not bought
with accuracy.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import warnings
from pathlib import Path

import numpy as np

from stablemofusion.motion.resample import resample
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

HERE = Path(__file__).resolve().parent


def aligned(joints: np.ndarray, frames: int) -> np.ndarray:
    """(T, 22, 3) joints at the origin facing +Z at the first frame (hips across X), resampled to ``frames``."""
    j = np.asarray(joints, float) - joints[0, 0] * np.array([1.0, 0.0, 1.0])
    across = j[0, 1] - j[0, 2]
    angle = np.arctan2(across[2], across[0])  # turn the hips' line onto +X
    c, s = np.cos(angle), np.sin(angle)
    turn = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    j = j @ turn.T
    return resample(j, len(j) - 1, frames - 1)[:frames]


def variety(motions: list[np.ndarray], pose_only: bool = False) -> float:
    """Mean over pairs of the mean joint distance (m); ``pose_only``: of the joints relative to the root (the
    body's movement without its path)."""
    if pose_only:
        motions = [m - m[:, :1] for m in motions]
    return float(np.mean([np.linalg.norm(a - b, axis=-1).mean() for a, b in itertools.combinations(motions, 2)]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--frames", type=int, default=64)
    ap.add_argument("--takes", type=int, default=12)
    ap.add_argument("--classifier", type=Path, default=None)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    rows = [json.loads(x) for x in (HERE / "prompts_plain.jsonl").read_text().splitlines() if x.strip()]
    clips = list(csv.DictReader((args.data / "clips.csv").open()))
    takes: dict[tuple[str, str], list[str]] = {}
    for c in clips:
        if c["dataset"] == "2":
            takes.setdefault((c["content"], c["style"]), []).append(c["id"])
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    hits: list[tuple[bool, bool]] = []
    if args.classifier is not None:
        from stablemofusion.data.labels import corpus_labels
        from stablemofusion.eval.classifier import dataset_labels, load_classifier

        classifier, allowed = load_classifier(args.classifier), dataset_labels(corpus_labels(args.data), 2)
    real: dict[tuple[str, str], float] = {}
    out = []
    for row in rows:
        label = (row["content"], row["style"])
        ids = takes.get(label, [])
        if len(ids) < 3:
            continue
        if label not in real:
            chosen = [ids[i] for i in np.linspace(0, len(ids) - 1, min(args.takes, len(ids))).astype(int)]
            motions = [aligned(np.load(args.data / "new_joints" / f"{i}.npy"), args.frames) for i in chosen]
            real[label] = (variety(motions), variety(motions, pose_only=True))
        results = pipe([row["prompt"]] * args.seeds, seed=list(range(args.seeds)))
        made = [aligned(r.joints, args.frames) for r in results]
        if args.classifier is not None:
            hits += [(c == label[0], s == label[1]) for c, s in classifier.predict([r.features for r in results],
                                                                                  [allowed] * len(results))]
        gen, pose = variety(made), variety(made, pose_only=True)
        out.append({"prompt": row["prompt"], "label": "/".join(label), "generated_m": round(gen, 3),
                    "real_m": round(real[label][0], 3), "ratio": round(gen / real[label][0], 2),
                    "pose_ratio": round(pose / real[label][1], 2)})
    ratios = np.array([o["ratio"] for o in out])
    poses = np.array([o["pose_ratio"] for o in out])
    print(json.dumps({"prompts": len(out), "labels": len(real), "ratio_median": round(float(np.median(ratios)), 2),
                      "ratio_p10_p90": [round(float(np.percentile(ratios, q)), 2) for q in (10, 90)],
                      "prompts_below_half": int((ratios < 0.5).sum()),
                      "pose_ratio_median": round(float(np.median(poses)), 2),
                      "pose_ratio_p10_p90": [round(float(np.percentile(poses, q)), 2) for q in (10, 90)],
                      "prompts_pose_below_half": int((poses < 0.5).sum()),
                      "generated_m_median": round(float(np.median([o["generated_m"] for o in out])), 3),
                      "real_m_median": round(float(np.median([o["real_m"] for o in out])), 3),
                      **({"content_accuracy": round(float(np.mean([h[0] for h in hits])), 3),
                          "style_accuracy": round(float(np.mean([h[1] for h in hits])), 3)} if hits else {})}))
    for o in sorted(out, key=lambda o: o["ratio"])[:12]:
        print(json.dumps(o))


if __name__ == "__main__":
    main()
