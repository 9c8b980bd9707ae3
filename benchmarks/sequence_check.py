"""Sequence prompts ("... then ...") drawn part by part: for each prompt of benchmarks/prompts_sequences.jsonl
(written before the sequence work), seeds 0-2, default settings on the ONNX backend, the motion classifier
names what each part's span shows, among its dataset's contents; a part is right when that is one of its
accepted contents. "whole" is the same prompt made as one motion (what the tool did before it split prompts),
judged on the same spans.

    python benchmarks/sequence_check.py --classifier CL --data CORPUS [--seeds 3]

Prints one markdown row per prompt (parts right, whole vs split) and the totals."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

PROMPTS = Path(__file__).resolve().parent / "prompts_sequences.jsonl"


def main() -> None:
    from stablemofusion.data.labels import corpus_labels
    from stablemofusion.eval.classifier import dataset_labels, load_classifier
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--classifier", type=Path, required=True)
    ap.add_argument("--data", type=Path, required=True, help="the labelled corpus the classifier was trained on")
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    classifier = load_classifier(args.classifier)
    labels = corpus_labels(args.data)
    contents = {d: dataset_labels(labels, d)[0] for d in (1, 2)}
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    rows = [json.loads(line) for line in PROMPTS.read_text(encoding="utf-8").splitlines() if line.strip()]
    totals = {"split": [], "whole": [], "both_split": [], "both_whole": []}
    print("| prompt | parts (seconds) | split: parts right | whole: parts right |")
    print("|---|---|---:|---:|")
    for row in rows:
        got = {"split": [], "whole": []}
        for seed in range(args.seeds):
            split = pipe(row["prompt"], seed=seed)[0]
            assert split.sequence is not None and len(split.sequence) == len(row["parts"]), split.sequence
            whole = pipe.timeline([(row["prompt"], split.frames / split.fps)], seed=seed)  # one motion, unsplit
            cuts = np.cumsum([0] + [int(round(s * split.fps)) for _, s in split.sequence])
            cuts[-1] = split.frames
            for name, r in (("split", split), ("whole", whole)):
                spans = [r.features[a:b] for a, b in zip(cuts[:-1], cuts[1:])]
                pred = classifier.predict(spans, [(contents[p["dataset"]], ()) for p in row["parts"]])
                ok = [c in p["content"] for (c, _), p in zip(pred, row["parts"])]
                got[name].append(ok)
                totals[name] += ok
                totals[f"both_{name}"].append(all(ok))
        parts = "; ".join(f"{p} ({s:.1f})" for p, s in split.sequence)
        cell = {k: f"{sum(map(sum, v))}/{sum(map(len, v))}" for k, v in got.items()}
        print(f"| {row['prompt']} | {parts} | {cell['split']} | {cell['whole']} |")
    print()
    for name in ("split", "whole"):
        print(f"{name}: parts right {np.mean(totals[name]):.2f} ({sum(totals[name])}/{len(totals[name])}), motions "
              f"with every part right {np.mean(totals['both_' + name]):.2f}")


if __name__ == "__main__":
    main()
