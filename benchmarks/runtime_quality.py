"""Quality on the portable runtime beside the torch path, in one run: prompt following on the free-form dev set (the
label classifier, 3 samples per prompt, 4 s, footskate post), skate with post and the out-of-domain decisions.

    python benchmarks/runtime_quality.py --classifier CL --data CORPUS
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--classifier", type=Path, required=True)
    ap.add_argument("--data", type=Path, required=True, help="the labelled corpus the classifier's labels come from")
    ap.add_argument("--prompts", type=Path, default=HERE / "prompts_freeform.jsonl")
    ap.add_argument("--samples", type=int, default=3)
    args = ap.parse_args()
    import torch

    from stablemofusion.eval.classifier import corpus_labels, load_classifier
    from stablemofusion.eval.prompts import load_prompts, prompt_accuracy
    from stablemofusion.footskate.metrics import mean_metrics
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    warnings.simplefilter("ignore")
    torch.set_num_threads(1)
    items, labels, classifier = load_prompts(args.prompts), corpus_labels(args.data), load_classifier(args.classifier)
    pipes = {"onnx": MotionPipeline.from_pretrained(backend="onnx", threads=1), "torch-eager": MotionPipeline.from_pretrained()}
    kw = {"onnx": {}, "torch-eager": {"engine": "eager"}}
    inside = [it.prompt for it in items if not it.ood]
    out, joints = {}, {}
    for name, pipe in pipes.items():
        acc = prompt_accuracy(pipe, classifier, items, labels, samples=args.samples, seconds=4.0, seed=0,
                              footskate="post", **kw[name])
        res = pipe(inside, seconds=4.0, seed=list(range(len(inside))), footskate="post", **kw[name])
        joints[name] = [r.joints for r in res]
        out[name] = {"accuracy": {k: v for k, v in acc.items() if k.startswith(("dataset", "all"))},
                     "skate_post": round(mean_metrics(joints[name])["skate_ratio"], 4),
                     "flagged_out_of_domain": sum(r.domain.out_of_domain for r in res)}
    out["max_joint_difference_mm"] = round(max(float(np.abs(a - b).max()) for a, b in
                                               zip(joints["onnx"], joints["torch-eager"])) * 1000, 4)
    print(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
