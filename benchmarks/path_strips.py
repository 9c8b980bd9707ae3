"""Path prompts seen from above (docs/paths.md): for a circle, a turn around, a zigzag and an explicit square path,
the root's path on the floor and the body every half second (lighter earlier), one panel each.

    python benchmarks/path_strips.py --out docs/images/paths_from_above.png
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from stablemofusion.motion.skeleton import HUMANML3D
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

CASES = [("a tired man walks in a circle then waves", None), ("a person turns around", None),
         ("a person walks in a zigzag", None), ("a person runs", [[0, 0], [0, 3], [3, 3], [3, 0]])]
PANEL, MARGIN = 360, 30


def panel(joints: np.ndarray, title: str, fps: float, path=None) -> Image.Image:
    img = Image.new("RGB", (PANEL, PANEL + 24), "white")
    d = ImageDraw.Draw(img)
    xz = joints[..., [0, 2]]
    lo, hi = xz.reshape(-1, 2).min(0) - 0.3, xz.reshape(-1, 2).max(0) + 0.3
    scale = (PANEL - 2 * MARGIN) / max(hi - lo)
    centre = (lo + hi) / 2
    # x to the right is the body's left (+X); seen from above with +Z up the page, +X is to the left of the page
    to_px = lambda p: (PANEL / 2 - (p[0] - centre[0]) * scale, PANEL / 2 - (p[1] - centre[1]) * scale)  # noqa: E731
    parents = HUMANML3D.parents
    step = int(fps / 2)
    frames = list(range(0, len(joints), step)) + [len(joints) - 1]
    for n, t in enumerate(frames):
        shade = int(200 - 170 * n / max(1, len(frames) - 1))
        for j, p in enumerate(parents):
            if p >= 0:
                d.line([to_px(xz[t, p]), to_px(xz[t, j])], fill=(shade, shade, shade), width=2)
    d.line([to_px(p) for p in xz[:, 0]], fill=(214, 39, 40), width=3)
    if path is not None:
        for p in path:
            x, y = to_px(p)
            d.ellipse([x - 6, y - 6, x + 6, y + 6], outline=(31, 119, 180), width=3)
    x, y = to_px(xz[0, 0])
    d.ellipse([x - 5, y - 5, x + 5, y + 5], fill=(44, 160, 44))
    d.text((8, PANEL + 4), title[:56], fill="black")
    return img


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    panels = []
    for prompt, path in CASES:
        r = pipe(prompt, seed=args.seed, path=path)[0]
        title = prompt if path is None else f"{prompt} --path square (blue)"
        panels.append(panel(r.joints, title, r.fps, path))
    out = Image.new("RGB", (PANEL * len(panels), PANEL + 24), "white")
    for k, p in enumerate(panels):
        out.paste(p, (k * PANEL, 0))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    out.save(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
