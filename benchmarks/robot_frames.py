"""Frames of the G1 (MuJoCo's offscreen renderer) doing a walk, a wave, a bow and a running circle, three frames each,
for docs/images/robot-g1.png.

    python benchmarks/robot_frames.py [--robot g1] [--out docs/images/robot-g1.png]
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.robots.files import render_frames
from stablemofusion.robots.model import load_robot
from stablemofusion.robots.retarget import retarget

PROMPTS = ("a person walks forward", "a person waves with the right hand", "a man bows", "a person runs in a circle")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robot", default="g1")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "images" / "robot-g1.png")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    robot = load_robot(args.robot)
    sheet = Image.new("RGB", (720, 300 * len(PROMPTS)))
    for row, prompt in enumerate(PROMPTS):
        r = pipe(prompt, seed=0)[0]
        motion = retarget(robot, r.joints, r.fps, r.contacts)
        picks = np.linspace(0, len(motion.qpos) - 1, 5).astype(int)[1:4]
        for i, frame in enumerate(render_frames(robot, motion.qpos[picks], size=(300, 240))):
            sheet.paste(Image.fromarray(frame), (240 * i, 300 * row))
        ImageDraw.Draw(sheet).text((6, 300 * row + 6), prompt, fill=(255, 255, 255))
    sheet.save(args.out, optimize=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
