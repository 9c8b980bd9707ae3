"""How many prompts the weak-action warning names, at margins and floors around the shipped ones: of the prompts
whose label is an action the model draws badly (they should be warned) and of the others (they should not), on a
labelled prompt file. The shipped margin and floor (core/reliability.py's WEAK_MARGIN, WEAK_FLOOR) are chosen on the
held-out lexicon probe and on benchmarks/prompts_weak_dev.jsonl; the free-form dev set and
benchmarks/prompts_weak_test.jsonl (written before the floor and the lexicon's examples, run once after) are not.

    python benchmarks/weak_warnings.py [--prompts FILE ...] [--margins 0.03 0.05 0.06 0.07 0.09] [--floors 0 0.4]

Prints one JSON line per file, margin and floor: weak prompts warned, those of them the out-of-domain warning names
instead (the weak warning is not given with it), other prompts warned (and which).
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

from stablemofusion.core.reliability import WEAK_FLOOR, WEAK_MARGIN, weak_action
from stablemofusion.eval.prompts import load_prompts
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

HERE = Path(__file__).resolve().parent
FILES = ("prompts_heldout_lexicon.jsonl", "prompts_weak_dev.jsonl", "prompts_freeform.jsonl", "prompts_weak_test.jsonl")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--prompts", type=Path, nargs="*", default=[HERE / f for f in FILES])
    ap.add_argument("--margins", type=float, nargs="*", default=[0.03, 0.05, WEAK_MARGIN, 0.07, 0.09])
    ap.add_argument("--floors", type=float, nargs="*", default=[0.0, WEAK_FLOOR])
    args = ap.parse_args()
    backend = MotionPipeline.from_pretrained(backend="onnx", threads=1).backend
    table = backend.reliability or {}
    weak = {a for a, r in table.items() if r.weak}
    for path in args.prompts:
        items = [it for it in load_prompts(path) if not it.ood]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            domains = backend.domains([it.prompt for it in items])
        should = [bool(set(it.contents) & weak) for it in items]
        for margin, floor in ((m, f) for f in args.floors for m in args.margins):
            hit = [weak_action(d, table, margin, floor) is not None for d in domains]
            print(json.dumps({"file": path.name, "margin": margin, "floor": floor,
                              "weak_warned": f"{sum(h and s for h, s in zip(hit, should))}/{sum(should)}",
                              "weak_out_of_domain": sum(d.out_of_domain for d, s in zip(domains, should) if s),
                              "others_warned": f"{sum(h and not s for h, s in zip(hit, should))}/{len(items) - sum(should)}",
                              "others": [it.prompt for it, h, s in zip(items, hit, should) if h and not s]}))


if __name__ == "__main__":
    main()
