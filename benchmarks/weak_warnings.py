"""How many prompts the weak-action warning names, at margins around the shipped one: of the prompts whose label is
an action the model draws badly (they should be warned) and of the others (they should not), on a labelled prompt
file. The shipped margin (core/reliability.py's WEAK_MARGIN) is chosen on the held-out lexicon probe and on
benchmarks/prompts_weak_dev.jsonl (written to tell waving from calling); the free-form dev set is a test set.

    python benchmarks/weak_warnings.py [--prompts FILE ...] [--margins 0.03 0.05 0.07 0.09]

Prints one JSON line per file and margin: weak prompts warned, other prompts warned (and which).
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

from stablemofusion.core.reliability import weak_action
from stablemofusion.eval.prompts import load_prompts
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

HERE = Path(__file__).resolve().parent
FILES = ("prompts_heldout_lexicon.jsonl", "prompts_weak_dev.jsonl", "prompts_freeform.jsonl")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--prompts", type=Path, nargs="*", default=[HERE / f for f in FILES])
    ap.add_argument("--margins", type=float, nargs="*", default=[0.03, 0.05, 0.07, 0.09])
    args = ap.parse_args()
    backend = MotionPipeline.from_pretrained(backend="onnx", threads=1).backend
    table = backend.reliability or {}
    weak = {a for a, r in table.items() if r.weak}
    for path in args.prompts:
        items = [it for it in load_prompts(path) if not it.ood]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            domains = backend.domains([it.prompt for it in items])
        for margin in args.margins:
            hit = [weak_action(d, table, margin) is not None for d in domains]
            should = [bool(set(it.contents) & weak) for it in items]
            print(json.dumps({"file": path.name, "margin": margin,
                              "weak_warned": f"{sum(h and s for h, s in zip(hit, should))}/{sum(should)}",
                              "others_warned": f"{sum(h and not s for h, s in zip(hit, should))}/{len(items) - sum(should)}",
                              "others": [it.prompt for it, h, s in zip(items, hit, should) if h and not s]}))


if __name__ == "__main__":
    main()
