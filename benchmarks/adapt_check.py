"""What an adapter taught and what it kept: a model with and without it (and optionally another beside them).

    python benchmarks/adapt_check.py --base checkpoints/no-run --adapter RUN.safetensors \
        --classifier CL --data CORPUS [--compare stablemofusion/assets/default_model] [--strips docs/images/x.png]

For each model (the base, the base with the adapter, and ``--compare`` if given):
- **taught action**: the held-out prompts of ``--prompts`` (benchmarks/adapt/run-prompts.txt: about running,
  written before any measurement), ``--samples`` seeds each, 4 s, footskate post; the motion classifier names
  each motion's content among dataset 2's (``--dataset``): the share named ``--action``; the root's mean speed;
- **other actions**: the free-form dev set (benchmarks/prompts_freeform.jsonl) without the taught action's
  prompts: content accuracy (3 samples, 4 s, post);
- **skate**: the skate ratio of the taught-action motions (post), beside real test-split clips of that action;
- **out of domain**: the share of taught-action prompts warned, and of the held-out foreign prompts
  (benchmarks/ood_heldout.txt);
- **speed**: one 4 s motion (batch 1) and 32 at once, text cached, footskate off, best of ``--repeats``.
Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).parent


def read_lines(path: Path) -> list[str]:
    return [s.strip() for s in path.read_text(encoding="utf-8").splitlines() if s.strip() and not s.startswith("#")]


def speed(pipe, repeats: int) -> dict:
    """Best seconds of one 4 s motion and of 32 (text cached, footskate off)."""
    prompts = ["a person runs forward"] * 32
    pipe.encode_text(prompts[:1])
    out = {}
    for n in (1, 32):
        pipe(prompts[:n], seconds=4, seed=list(range(n)), footskate="off")  # warm
        best = float("inf")
        for _ in range(repeats):
            t = time.perf_counter()
            pipe(prompts[:n], seconds=4, seed=list(range(n)), footskate="off")
            best = min(best, time.perf_counter() - t)
        out[f"batch_{n}_ms"] = round(best * 1000, 1)
    return out


LEFT_FOOT, RIGHT_FOOT = (7, 10), (8, 11)  # ankle and toe joints


def hops_on_one_leg(joints: np.ndarray, lifted: float = 0.05) -> bool:
    """Whether a motion (T, 22, 3) at 20 fps hops on one leg: one foot stays more than ``lifted`` m above the
    floor (the motion's lowest foot joints) on at least 70% of frames while the hips bob up and down at least
    0.3 m/s on average. Thresholds set on real motion (printed by this script): the capture's 4 s windows and
    the corpus's test clips."""
    feet = joints[:, list(LEFT_FOOT + RIGHT_FOOT), 1]
    floor = float(np.percentile(feet, 1))
    left = joints[:, LEFT_FOOT, 1].min(axis=1) - floor > lifted
    right = joints[:, RIGHT_FOOT, 1].min(axis=1) - floor > lifted
    bob = float(np.abs(np.diff(joints[:, 0, 1])).mean() * 20.0)
    return bool(max(left.mean(), right.mean()) >= 0.7 and bob >= 0.3)


def root_speed(joints: np.ndarray, fps: float) -> float:
    """Mean horizontal speed of the root (m/s) of joints (T, 22, 3)."""
    return float(np.linalg.norm(np.diff(joints[:, 0, [0, 2]], axis=0), axis=1).mean() * fps)


def real_clips(data: Path, action: str | None, split: str | None = "test", dataset: int = 2) -> list[np.ndarray]:
    """Joints of the corpus's clips of ``dataset`` and ``action`` (None: every action) in ``split`` (None: all)."""
    import csv

    rows = [r for r in csv.DictReader(open(data / "clips.csv"))
            if action in (None, r["content"]) and r["dataset"] == str(dataset)]
    ids = set((data / f"{split}.txt").read_text().split()) if split else {r["id"] for r in rows}
    return [np.load(data / "new_joints" / f"{r['id']}.npy") for r in rows if r["id"] in ids]


def main() -> None:
    from stablemofusion.data.labels import corpus_labels
    from stablemofusion.eval.classifier import dataset_labels, load_classifier
    from stablemofusion.eval.prompts import load_prompts, prompt_accuracy
    from stablemofusion.footskate.metrics import mean_metrics
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, default=None, help="the model the adapter was made for (default: shipped)")
    ap.add_argument("--adapter", type=Path, action="append", required=True)
    ap.add_argument("--compare", type=Path, default=None, help="another model folder measured beside them")
    ap.add_argument("--classifier", type=Path, required=True)
    ap.add_argument("--data", type=Path, required=True, help="the labelled corpus (real clips for the skate figure)")
    ap.add_argument("--action", default="run", help="the taught action: a classifier label, or 'hop' (hopping on "
                                                    "one leg: hops_on_one_leg on the joints)")
    ap.add_argument("--hop-reference", type=Path, default=None,
                    help="with --action hop: S1_Hopping.pth, to check the hop detector on the real capture")
    ap.add_argument("--dataset", type=int, choices=(1, 2), default=2,
                    help="the corpus dataset whose contents the classifier chooses among (and whose real clips of "
                         "--action are the reference)")
    ap.add_argument("--prompts", type=Path, default=HERE / "adapt" / "run-prompts.txt")
    ap.add_argument("--samples", type=int, default=3)
    ap.add_argument("--others", type=Path, default=HERE / "prompts_freeform.jsonl")
    ap.add_argument("--skip-others", action="store_true")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--strips", type=Path, default=None, help="PNG: three taught-action prompts, a row per model")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    warnings.simplefilter("ignore")
    classifier = load_classifier(args.classifier)
    labels = corpus_labels(args.data)
    allowed = dataset_labels(labels, args.dataset)
    prompts = read_lines(args.prompts)
    foreign = read_lines(HERE / "ood_heldout.txt")
    others = [it for it in load_prompts(args.others) if args.action not in it.contents and not it.ood]
    base = MotionPipeline.from_pretrained(args.base, device="cpu")
    models = {"base": base, "base+adapter": base.with_adapters(args.adapter)}
    if args.compare is not None:
        models["compare"] = MotionPipeline.from_pretrained(args.compare, device="cpu")
    report: dict = {"prompts": len(prompts), "samples": args.samples, "others": len(others), "models": {}}
    if args.action == "hop":  # the detector on real motion: the capture's 3 s windows, and the corpus's test clips
        test = [j for j in real_clips(args.data, None) if len(j) >= 40]
        report["hop_detector_on_real"] = {"corpus_test_clips": round(float(np.mean([hops_on_one_leg(j)
                                                                                     for j in test])), 3)}
        if args.hop_reference is not None:
            from stablemofusion.footskate.underpressure import load_s1, retarget_23_to_22

            hop = retarget_23_to_22(load_s1(args.hop_reference)["joints"])
            windows = [hop[a:a + 80] for a in range(0, len(hop) - 80, 40)]
            report["hop_detector_on_real"]["s1_hopping_4s_windows"] = round(float(np.mean(
                [hops_on_one_leg(w) for w in windows])), 3)
            report["real_skate"] = mean_metrics(windows)["skate_ratio"]
    else:
        real = real_clips(args.data, args.action, dataset=args.dataset)
        if not real:  # no test clip of this action: all of them (the reference may then hold the taught clips)
            real, report["real_split"] = real_clips(args.data, args.action, None, args.dataset), "all"
        report["real_skate"] = mean_metrics(real)["skate_ratio"]
        report["real_root_speed_m_s"] = round(float(np.mean([root_speed(j, 20.0) for j in real])), 3)
    seeds = [k for _ in prompts for k in range(args.samples)]
    rep = [p for p in prompts for _ in range(args.samples)]
    strips = []
    for name, pipe in models.items():
        t0 = time.perf_counter()
        res = []
        for a in range(0, len(rep), 32):
            res += pipe(rep[a:a + 32], seconds=4, seed=seeds[a:a + 32], footskate="post")
        pred = classifier.predict([r.features for r in res], [allowed] * len(res))
        hit = [hops_on_one_leg(r.joints) for r in res] if args.action == "hop" else [p[0] == args.action for p in pred]
        speeds = [root_speed(r.joints, r.fps) for r in res]
        row = {"taught_accuracy": round(float(np.mean(hit)), 3),
               "per_prompt": {p: round(float(np.mean(hit[i * args.samples:(i + 1) * args.samples])), 2)
                              for i, p in enumerate(prompts)},
               "predicted": {c: sum(p[0] == c for p in pred) for c in sorted({p[0] for p in pred})},
               "root_speed_m_s": round(float(np.mean(speeds)), 3),
               "skate_post": round(mean_metrics([r.joints for r in res])["skate_ratio"], 4),
               "warned_taught": round(float(np.mean([pipe.known_actions.check(p).out_of_domain for p in prompts])), 3),
               "warned_foreign": round(float(np.mean([pipe.known_actions.check(p).out_of_domain for p in foreign])), 3)}
        if not args.skip_others:
            acc = prompt_accuracy(pipe, classifier, others, labels, samples=3, seconds=4.0, footskate="post")
            row["others_content_accuracy"] = {k: round(v["content_acc"], 3) for k, v in acc.items()
                                              if isinstance(v, dict) and "content_acc" in v}
        row["speed"] = speed(pipe, args.repeats)
        row["seconds"] = round(time.perf_counter() - t0, 1)
        report["models"][name] = row
        strips += [(f"{name}: {p}", r.joints) for p, r in zip(prompts[:3], res[::args.samples][:3])]
        print(name, json.dumps(row), flush=True)
    if args.strips is not None:
        from stablemofusion.render import render_strip

        order = [s for k in range(3) for s in strips[k::3]]
        render_strip(order, [0, 16, 32, 48, 64, 79], args.strips, size=180)
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
