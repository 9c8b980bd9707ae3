"""Frame strips of every editing mode and of a timeline, for docs/editing.md.

    python benchmarks/edit_strips.py [--out docs/images] [--seed 0]

Source: the packaged example motion (a captured two-hand wave, Bandai-Namco, CC BY-NC 4.0). Each strip shows
the source (top row) and the edit (bottom row) at the same frames.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

EDITS = [  # file name, prompt, mode, options
    ("edit_prefix", "a person jumps up and down", "prefix", dict(keep_start=1.5)),
    ("edit_suffix", "a person bows", "suffix", dict(keep_end=1.5)),
    ("edit_inbetween", "a person turns around", "inbetween", dict(keep_start=1.5, keep_end=1.5)),
    ("edit_upper_body", "a person punches forward", "upper-body", {}),
    ("edit_lower_body", "a person walks forward", "lower-body", {}),
    ("edit_trajectory", "a person walks", "trajectory", {}),
]


def main() -> None:
    from stablemofusion.core.edit_plan import source_features
    from stablemofusion.motion.features import joints_from_features
    from stablemofusion.motion.files import load_motion
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.render import render_strip

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("docs/images"))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    pipe = MotionPipeline.from_pretrained(device="cpu")
    src = source_features(load_motion("example:wave-both-hands"), pipe.skeleton, pipe.fps)
    ref = joints_from_features(src, pipe.skeleton)
    T = len(src)
    for name, prompt, mode, kw in EDITS:
        path = None
        if mode == "trajectory":  # an arc to the right, 4 m, over the source's length
            t = np.linspace(0, 1, T)
            path = np.stack([-np.sin(t * np.pi / 2) * 2.0, np.sin(t * np.pi / 2) * 2.0 + t * 1.0], -1)
        r = pipe.edit(prompt, src, mode, seed=args.seed, path=path, **kw)
        frames = [int(x) for x in np.linspace(0, len(r.joints) - 1, 7).round()]
        label = ", ".join(f"{k.replace('_', '-')} {v:g} s" for k, v in kw.items())
        rows = [("source: a captured two-hand wave", ref), (f"{mode} ({label or 'whole motion'}): {prompt}", r.joints)]
        if mode == "trajectory":
            rows = [(f"trajectory (an arc 2 m to the right, 3 m forward): {prompt}", r.joints)]
        print(render_strip(rows, frames, args.out / f"{name}.png", size=170))
    r = pipe.timeline([("a person walks forward", 8.0), ("a person waves both hands", 6.0), ("a person bows", 6.0)],
                      seed=args.seed)
    frames = [40, 120, 170, 200, 250, 290, 320, 350, 390]  # walk, walk, wave x 3, bow x 4
    print(render_strip([(f"timeline: {r.prompt}", r.joints)], frames, args.out / "timeline.png", size=220))


if __name__ == "__main__":
    main()
