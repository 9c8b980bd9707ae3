"""Frame strips of the README example and a few free-form prompts, old model vs new, for docs/prompts.md.

    python benchmarks/prompt_strips.py --old OLD_MODEL --new NEW_MODEL --out docs/images
"""

from __future__ import annotations

import argparse
from pathlib import Path

PROMPTS = ["a person waves both hands happily", "a tired old man shuffles forward"]
FRAMES = [0, 16, 32, 48, 64, 79]


def main() -> None:
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.render import render_strip

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, required=True)
    ap.add_argument("--new", type=Path, default=None, help="default: the shipped model")
    ap.add_argument("--out", type=Path, default=Path("docs/images"))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    pipes = {"before": MotionPipeline.from_pretrained(args.old, device="cpu"),
             "now": MotionPipeline.from_pretrained(args.new, device="cpu")}
    for i, prompt in enumerate(PROMPTS):
        rows = []
        for name, pipe in pipes.items():
            r = pipe(prompt, seconds=4, seed=args.seed)[0]
            rows.append((f"{name}: {prompt}", r.joints))
        path = render_strip(rows, FRAMES, args.out / f"prompt_{i}.png", size=200)
        print(path)


if __name__ == "__main__":
    main()
