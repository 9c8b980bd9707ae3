"""Per-action content accuracy from `smf evaluate --prompts FILE --out OUT.json` results, side by side.

    python benchmarks/per_action.py --prompts benchmarks/prompts_freeform.jsonl A.json B.json ...

Prints one markdown row per (dataset, action) of the prompt file: the number of prompts, then for each result
file the share of its motions whose classified content is the prompt's action (docs/prompts.md).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path


def per_action(result: Path, dataset_of: dict[str, object]) -> dict[tuple[str, str], tuple[int, int, int]]:
    """(dataset, action) -> (motions right, motions, prompts) of one `smf evaluate --out` file."""
    acc: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0, 0])
    for p in json.loads(result.read_text())["prompts"]["per_prompt"]:
        want = p["want"][0][0]
        row = acc[(str(dataset_of.get(p["prompt"], "-")), want)]
        row[2] += 1
        for got in p["got"]:
            row[0] += got[0] == want
            row[1] += 1
    return {k: tuple(v) for k, v in acc.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prompts", type=Path, required=True, help="the prompt file the results were made from")
    ap.add_argument("results", type=Path, nargs="+")
    args = ap.parse_args()
    rows = [json.loads(line) for line in args.prompts.read_text(encoding="utf-8").splitlines() if line.strip()]
    dataset_of = {r["prompt"]: r.get("dataset") for r in rows}
    tables = [per_action(f, dataset_of) for f in args.results]
    print("| dataset | action | prompts | " + " | ".join(f.stem for f in args.results) + " |")
    print("|---|---|---:|" + "---:|" * len(tables))
    for key in sorted(set().union(*tables)):
        prompts = next(t[key][2] for t in tables if key in t)
        cells = [f"{t[key][0] / t[key][1]:.2f}" if key in t and t[key][1] else "-" for t in tables]
        print(f"| {key[0]} | {key[1]} | {prompts} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
