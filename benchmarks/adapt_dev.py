"""Development figures of adapters (what their settings were chosen on; the held-out ones: adapt_check.py).

    python benchmarks/adapt_dev.py run --base checkpoints/no-run --classifier CL --data CORPUS ADAPTER [ADAPTER ...]
    python benchmarks/adapt_dev.py hop ADAPTER [ADAPTER ...]          # adapters of the shipped model

``run``: the running development prompts (benchmarks/adapt/run-dev-prompts.txt, plain and styled, 3 seeds each,
4 s, footskate off) named "run" by the motion classifier, their root speed, and the other actions' dataset-2
captions of the lexicon's held-out words (3 per content and style, one seed each): content accuracy, walking
alone, and the share taken for running. ``hop``: benchmarks/adapt/hop-dev-prompts.txt (3 seeds, 4 s, post)
hopping on one leg by adapt_check.py's rule. ``-`` as an adapter: the base alone.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def read_prompts(path: Path, section: str | None = None) -> list[str]:
    """The prompts of ``path`` (``# [section]`` lines start sections; None: every prompt)."""
    out, current = [], None
    for line in path.read_text(encoding="utf-8").splitlines():
        line = line.strip()
        if line.startswith("# ["):
            current = line[3:line.index("]")]
        elif line and not line.startswith("#") and (section is None or current == section):
            out.append(line)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("task", choices=("run", "hop"))
    ap.add_argument("adapters", nargs="+")
    ap.add_argument("--base", type=Path, default=None)
    ap.add_argument("--classifier", type=Path, default=None)
    ap.add_argument("--data", type=Path, default=None, help="the labelled corpus (its label table)")
    ap.add_argument("--teacher", action="store_true", help="the adapted teacher instead of the student")
    ap.add_argument("--guidance", type=float, default=None, help="guidance scale (default: the model's)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    import torch

    from adapt_check import hops_on_one_leg, root_speed
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    warnings.simplefilter("ignore")
    torch.set_num_threads(args.threads)
    if args.task == "run":
        from stablemofusion.data.captions import captions_for
        from stablemofusion.data.labels import corpus_labels
        from stablemofusion.data.lexicon import load_lexicon
        from stablemofusion.eval.classifier import dataset_labels, load_classifier

        if args.classifier is None or args.data is None:
            ap.error("run needs --classifier and --data")
        classifier, labels = load_classifier(args.classifier), corpus_labels(args.data)
        allowed = dataset_labels(labels, 2)
        contents, styles = load_lexicon("bandai").datasets[2]
        others = [(c, t) for c in contents if c != "run" for s in styles
                  for t, _ in captions_for(c, s, 3, seed="dev", heldout=True)]
        path = HERE / "adapt" / "run-dev-prompts.txt"
        sections = {"plain": read_prompts(path, "plain"), "styled": read_prompts(path, "styled")}
    else:
        sections = {"hop": read_prompts(HERE / "adapt" / "hop-dev-prompts.txt")}
    base = MotionPipeline.from_pretrained(args.base, device="cpu", teacher=args.teacher)
    for name in args.adapters:
        pipe = base if name == "-" else base.with_adapters([Path(name)])
        row = {}
        for section, prompts in sections.items():
            items = [p for p in prompts for _ in range(3)]
            res = pipe(items, seconds=4, seed=[k % 3 for k in range(len(items))], guidance_scale=args.guidance,
                       footskate="off" if args.task == "run" else "post")
            if args.task == "run":
                pred = classifier.predict([r.features for r in res], [allowed] * len(res))
                row[section] = round(float(np.mean([p[0] == "run" for p in pred])), 3)
                row[f"{section}_speed_m_s"] = round(float(np.mean([root_speed(r.joints, r.fps) for r in res])), 2)
            else:
                row[section] = round(float(np.mean([hops_on_one_leg(r.joints) for r in res])), 3)
        if args.task == "run":
            res = pipe([t for _, t in others], seconds=4, seed=list(range(len(others))), footskate="off",
                       guidance_scale=args.guidance)
            pred = [p[0] for p in classifier.predict([r.features for r in res], [allowed] * len(res))]
            row["others"] = round(float(np.mean([p == c for p, (c, _) in zip(pred, others)])), 3)
            row["walk"] = round(float(np.mean([p == c for p, (c, _) in zip(pred, others) if c == "walk"])), 3)
            row["others_as_run"] = round(float(np.mean([p == "run" for p in pred])), 3)
        print(Path(name).name, row, flush=True)


if __name__ == "__main__":
    main()
