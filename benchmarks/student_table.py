"""Quality of a distilled student against its teacher over step counts (docs/inference.md, 'Few-step student').

For each (model, steps): content/style accuracy of held-out probe prompts (and of the free-form dev set, with
--freeform), judged by the motion classifier, and FID / top-3 of our evaluator on the first --fid-items items
of one fixed draw of a split: the figures `smf train --eval-every` records (eval/monitor.py), at a chosen step
count. Every model samples with its own default sampler (the student: lcm; the teacher: SDE-DPM-Solver++ 2M
Karras) and its own default guidance unless --guidance is given (the shipped student 2.5 as its input, the shipped
teacher 1.0), the same seeds for all; each
row records its guidance.

    OMP_NUM_THREADS=1 python benchmarks/student_table.py --student RUN --teacher MODEL --data CORPUS \
        --probe benchmarks/prompts_heldout_lexicon.jsonl --classifier CL --evaluator EV --out table.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


class AtSteps:
    """A pipeline whose text-to-motion calls use ``steps`` (everything else is the pipeline's)."""

    def __init__(self, pipe, steps: int, sampler: str | None = None):
        self.pipe, self.steps, self.sampler = pipe, steps, sampler

    def __call__(self, *args, **kw):
        return self.pipe(*args, steps=self.steps, sampler=self.sampler, **kw)

    def __getattr__(self, name):
        return getattr(self.pipe, name)


def measure(pipe, steps: int, args, classifier, labels, probes: dict, evaluator, sampler: str | None = None) -> dict:
    from stablemofusion.eval.monitor import PROBE_SECONDS
    from stablemofusion.eval.prompts import prompt_accuracy
    from stablemofusion.eval.protocol import EmbeddingModel, EvalConfig, evaluate

    from stablemofusion.core.settings import Settings

    s = pipe.settings(Settings(guidance_scale=args.guidance, sampler=sampler))
    row: dict = {"steps": steps, "sampler": s.sampler, "guidance": s.guidance_scale}
    t0 = time.perf_counter()
    for name, items in probes.items():
        acc = prompt_accuracy(AtSteps(pipe, steps, sampler), classifier, items, labels, samples=args.samples,
                              seconds=PROBE_SECONDS, seed=args.seed, guidance_scale=s.guidance_scale)
        row[f"{name}_content"] = round(acc["all"]["content_acc"], 4)
        row[f"{name}_style"] = round(acc["all"]["style_acc"], 4)
    if evaluator is not None:
        for split in args.splits.split(","):
            cfg = EvalConfig(replications=1, mm_captions=0, max_items=args.fid_items, split=split, seed=args.seed,
                             batch_size=32, steps=steps, sampler=sampler, guidance_scale=s.guidance_scale)
            res = evaluate(pipe, EmbeddingModel(evaluator, pipe.text_cache), args.data, cfg, progress=False)
            gen = res["rows"]["Generated"]
            row[f"{split}_fid"] = round(float(gen["fid"][0]), 3)
            row[f"{split}_top3"] = round(float(gen["top3"][0]), 4)
    row["seconds"] = round(time.perf_counter() - t0, 1)
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--student", type=Path, default=None, help="the student (none: teacher rows only)")
    p.add_argument("--teacher", type=Path, default=None, help="default: the shipped model's teacher")
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--probe", type=Path, required=True)
    p.add_argument("--freeform", type=Path, default=None, help="also the free-form dev set")
    p.add_argument("--classifier", type=Path, required=True)
    p.add_argument("--evaluator", type=Path, default=None)
    p.add_argument("--fid-items", type=int, default=256)
    p.add_argument("--splits", default="val", help="comma list of splits for FID (val, test)")
    p.add_argument("--student-steps", default="1,2,4,8")
    p.add_argument("--teacher-steps", default="1,2,4,8,10")
    p.add_argument("--teacher-sampler", default=None, help="default: the teacher's own")
    p.add_argument("--guidance", type=float, default=None, help="guidance scale of every row (default: each model's)")
    p.add_argument("--samples", type=int, default=1, help="motions per prompt")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args()

    import torch

    torch.set_num_threads(args.threads)
    from stablemofusion.eval.classifier import corpus_labels, load_classifier
    from stablemofusion.eval.prompts import check_known, load_prompts
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    classifier = load_classifier(args.classifier)
    labels = corpus_labels(args.data)
    probes = {"probe": [it for it in load_prompts(args.probe) if not it.ood]}
    if args.freeform is not None:
        probes["freeform"] = [it for it in load_prompts(args.freeform) if not it.ood]
    for items in probes.values():
        check_known(items, classifier)
    evaluator = None
    if args.evaluator is not None:
        from stablemofusion.eval.evaluator import load_evaluator

        evaluator, _ = load_evaluator(args.evaluator)
    rows = []
    for who, path, steps_list in (("student", args.student, args.student_steps),
                                  ("teacher", args.teacher, args.teacher_steps)):
        if who == "student" and path is None:
            continue
        pipe = MotionPipeline.from_pretrained(path, teacher=who == "teacher" and path is None, device="cpu")
        for steps in (int(s) for s in steps_list.split(",") if s):
            sampler = args.teacher_sampler if who == "teacher" else None
            row = {"model": who, **measure(pipe, steps, args, classifier, labels, probes, evaluator, sampler)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    keys = [k for k in rows[0] if k not in ("model", "steps", "sampler", "guidance", "seconds")]
    lines = ["| model | sampler | steps | guidance | " + " | ".join(keys) + " |", "|---" * (4 + len(keys)) + "|"]
    for r in rows:
        lines.append(f"| {r['model']} | {r['sampler']} | {r['steps']} | {r['guidance']:g} | "
                     + " | ".join(str(r.get(k)) for k in keys) + " |")
    print("\n".join(lines))
    if args.out is not None:
        args.out.write_text(json.dumps({"rows": rows, "args": {k: str(v) for k, v in vars(args).items()}}, indent=2)
                            + "\n")


if __name__ == "__main__":
    main()
