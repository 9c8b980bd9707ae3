"""Every step count from 1 to 100 at every door: a sane motion or a clear one-line error, never a 200 of garbage.

For the shipped student (and, with --teacher, its teacher): the library (`pipe(...)`), the HTTP API (the app
in-process) and `smf generate` (its entry point, in-process) with `--steps N` for N = 1..100, a few prompts of
4 s each. Prints JSON: per door, the step counts answered with a motion, those refused (and the distinct
refusal lines), and the largest root speed (m/s) and joint height (m) among the motions answered.

    OMP_NUM_THREADS=1 python benchmarks/steps_sweep.py [--teacher] [--max-steps 100]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import tempfile
from pathlib import Path

import numpy as np
import torch

from stablemofusion.cli.main import main
from stablemofusion.core.errors import SMFError
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve import create_app

PROMPTS = ["a person runs forward", "a person waves both hands", "an old man walks in a circle"]


def measure(joints: np.ndarray, fps: float) -> tuple[float, float]:
    root = joints[:, 0, [0, 2]]
    speed = float((np.linalg.norm(root[5:] - root[:-5], axis=-1) * fps / 5).max())
    return speed, float(np.abs(joints[..., 1]).max())


def _ranges(values: list[int]) -> str:
    """[1, 2, 3, 7, 8] -> '1-3, 7-8'."""
    out, start = [], None
    for i, v in enumerate(values):
        start = v if start is None else start
        if i + 1 == len(values) or values[i + 1] != v + 1:
            out.append(f"{start}-{v}" if v != start else f"{v}")
            start = None
    return ", ".join(out) or "none"


def sweep(door, steps_range) -> dict:
    ok, refused, lines, speed, height = [], [], set(), 0.0, 0.0
    for steps in steps_range:
        got = door(steps)
        if isinstance(got, str):
            refused.append(steps)
            lines.add(re.sub(r"got \d+", "got N", got.strip()))  # one line per kind of refusal
        else:
            ok.append(steps)
            for s, h in got:
                speed, height = max(speed, s), max(height, h)
    return {"answered": _ranges(ok), "refused": _ranges(refused), "refusals": sorted(lines),
            "max_root_speed_m_s": round(speed, 2),
            "max_joint_height_m": round(height, 2)}


def main_() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--teacher", action="store_true")
    p.add_argument("--max-steps", type=int, default=100)
    args = p.parse_args()
    torch.set_num_threads(1)
    pipe = MotionPipeline.from_pretrained(teacher=args.teacher, device="cpu")
    app = create_app(pipe)
    from fastapi.testclient import TestClient

    def library(steps):
        try:
            return [measure(r.joints, r.fps) for r in pipe(PROMPTS, seconds=4, seed=[0, 1, 2], steps=steps)]
        except SMFError as e:
            return str(e)

    client = None

    def http(steps):
        out = []
        for i, prompt in enumerate(PROMPTS):
            r = client.post("/v1/generate", json={"prompt": prompt, "seconds": 4, "seed": i, "steps": steps})
            if r.status_code != 200:
                assert 400 <= r.status_code < 500, r.text
                return r.json()["error"]
            out.append(measure(np.array(r.json()["joints"]), r.json()["fps"]))
        return out

    def cli(steps):
        with tempfile.TemporaryDirectory() as d:
            argv = ["generate", PROMPTS[0], "--seconds", "4", "--seed", "0", "--steps", str(steps), "--out", d,
                    "--format", "npy"] + (["--teacher"] if args.teacher else [])
            err = io.StringIO()
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                code = main(argv)
            if code != 0:
                assert code == 2 and err.getvalue().count("\n") == 1, err.getvalue()
                return err.getvalue()
            return [measure(np.load(next(Path(d).glob("*_joints.npy"))), 20.0)]

    steps = range(1, args.max_steps + 1)
    report = {"model": "teacher" if args.teacher else "student", "prompts": PROMPTS, "library": sweep(library, steps)}
    # the app's worker thread warms the pipeline when it starts: not beside the library's calls (diffusers imports
    # its schedulers lazily, and two threads importing one at once can see it half made)
    with TestClient(app, base_url="http://127.0.0.1") as client:
        report["http"] = sweep(http, steps)
    report["cli"] = sweep(cli, steps)
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main_()
