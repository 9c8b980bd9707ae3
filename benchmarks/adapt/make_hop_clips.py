"""A user-style folder of a move the corpus lacks: hopping on one leg, from UnderPressure's S1_Hopping capture.

    python benchmarks/adapt/make_hop_clips.py --s1 ../shared/data/underpressure/S1_Hopping.pth --n 30 --out DIR

The capture (one subject, 54.5 s at 100 fps; non-commercial licence) hops on the right leg for about 22 s,
then on the left. It is cut into ``--n`` windows of 3 s spread evenly over it (overlapping when n > 18), each
written as a BVH file of our 22-joint skeleton (read back with ``--joint-map humanml3d``), with a caption
written by hand for the leg it hops on (the leg is measured: the other foot stays off the floor).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

WINDOW = 60  # frames at 20 fps (3 s)
# captions written by hand, the way a user would label their takes; cycled through per leg
CAPTIONS = {
    "right": ["a person hops on their right leg", "someone hops forward on the right foot",
              "a man hops on one leg, the right one", "a person jumps repeatedly on the right leg",
              "hopping on the right foot"],
    "left": ["a person hops on their left leg", "someone hops forward on the left foot",
             "a man hops on one leg, the left one", "a person jumps repeatedly on the left leg",
             "hopping on the left foot"],
}
LEFT_FOOT, RIGHT_FOOT = (7, 10), (8, 11)  # ankle and toe joints


def hopping_leg(joints: np.ndarray, floor: float) -> str:
    """The leg a window hops on: the one whose foot is on the floor more often."""
    up = lambda feet: float((joints[:, feet, 1].min(axis=1) - floor > 0.05).mean())  # noqa: E731
    return "right" if up(LEFT_FOOT) > up(RIGHT_FOOT) else "left"


def main() -> None:
    from stablemofusion.footskate.underpressure import load_s1, retarget_23_to_22
    from stablemofusion.motion.files import load_motion, save_motion

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--s1", type=Path, required=True)
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    joints = retarget_23_to_22(load_s1(args.s1)["joints"])  # (T, 22, 3) at 20 fps
    floor = float(joints[:, [7, 8, 10, 11], 1].min())
    args.out.mkdir(parents=True, exist_ok=True)
    starts = np.linspace(0, len(joints) - WINDOW, args.n).round().astype(int)
    count = {"right": 0, "left": 0}
    rows = []
    for k, s in enumerate(starts):
        window = joints[s:s + WINDOW]
        leg = hopping_leg(window, floor)
        caption = CAPTIONS[leg][count[leg] % len(CAPTIONS[leg])]
        count[leg] += 1
        name = f"hop_{k:02d}.bvh"
        np.save(args.out / "window.npy", window.astype(np.float32))
        save_motion(load_motion(args.out / "window.npy"), args.out / name, "bvh")
        rows.append((name, caption))
    (args.out / "window.npy").unlink()
    with open(args.out / "captions.csv", "w", newline="") as f:
        csv.writer(f).writerows([("file", "caption"), *rows])
    print(f"{len(rows)} clips in {args.out}: {count['right']} on the right leg, {count['left']} on the left")


if __name__ == "__main__":
    main()
