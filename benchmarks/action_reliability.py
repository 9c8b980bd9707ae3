"""The shipped model's reliability per known action, as data: how often its motions for held-out wording are
judged to be the action, and how many corpus clips taught it. Writes stablemofusion/assets/default_model/
reliability.json, which the pipelines read to warn about prompts whose closest action the model draws badly.

    smf evaluate --data CORPUS --classifier CL --prompts benchmarks/prompts_heldout_lexicon.jsonl --prompts-only \\
        --out HELDOUT.json
    python benchmarks/action_reliability.py --result HELDOUT.json --data CORPUS [--write]

An action is weak when the corpus holds fewer than MIN_CLIPS clips of it and fewer than half of its held-out
prompts' motions are judged right (both: a low score with many clips is as likely the judge's as the model's).
"""

from __future__ import annotations

import argparse
import csv
import json
from collections import defaultdict
from pathlib import Path

MIN_CLIPS = 10
MIN_ACCURACY = 0.5
OUT = Path(__file__).resolve().parents[1] / "stablemofusion" / "assets" / "default_model" / "reliability.json"


def fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--result", type=Path, required=True, help="`smf evaluate --prompts ... --out` of the held-out probe")
    ap.add_argument("--data", type=Path, required=True, help="the corpus (clips.csv) the model was trained on")
    ap.add_argument("--write", action="store_true", help=f"write {OUT.name} into the shipped model's folder")
    args = ap.parse_args()
    right, total = defaultdict(int), defaultdict(int)
    for p in json.loads(args.result.read_text())["prompts"]["per_prompt"]:
        want = p["want"][0]
        for got in p["got"]:
            total[want[0]] += 1
            right[want[0]] += got[0] in want
    clips = defaultdict(int)
    with (args.data / "clips.csv").open() as f:
        for row in csv.DictReader(f):
            clips[row["content"]] += 1
    actions = {}
    for a in sorted(set(total) | set(clips)):
        acc = right[a] / total[a] if total[a] else None
        weak = clips[a] < MIN_CLIPS and acc is not None and acc < MIN_ACCURACY
        actions[a] = {"accuracy": None if acc is None else round(acc, 2), "motions": total[a], "clips": clips[a],
                      "weak": weak}
    table = {"about": "Per known action: the share of motions judged to be it (motion classifier) for held-out "
                      "wording (benchmarks/prompts_heldout_lexicon.jsonl, 3 seeds), and the corpus clips that taught "
                      f"it; weak: fewer than {MIN_CLIPS} clips and an accuracy under {MIN_ACCURACY} "
                      "(benchmarks/action_reliability.py).", "actions": actions}
    print("| action | held-out accuracy | motions | corpus clips | warned |")
    print("|---|---:|---:|---:|---|")
    for a, r in actions.items():
        print(f"| {a} | {fmt(r['accuracy'])} | "
              f"{r['motions']} | {r['clips']} | {'yes' if r['weak'] else ''} |")
    if args.write:
        OUT.write_text(json.dumps(table, indent=1) + "\n", encoding="utf-8")
        print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
