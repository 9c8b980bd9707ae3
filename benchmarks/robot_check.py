"""Motions retargeted to the shipped robots, checked in MuJoCo: joint-limit violations, self-contacts, planted feet
on the floor and their sliding against the human's, keypoint tracking error, joint speeds, the time to retarget,
and an open-loop replay of a 10 s trajectory with the robot's own actuators on a floor.

    python benchmarks/robot_check.py [--robots g1,h1] [--sets freeform,paths] [--n 0] [--seed 0]
    python benchmarks/robot_check.py replay [--robots g1,h1]

Prompts: the free-form dev prompts (benchmarks/prompts_freeform.jsonl) and the path prompts
(benchmarks/paths/heldout.jsonl), default settings, lengths from the model. Time: one thread, a 4 s motion
("a person walks forward", median of 5), against generating it.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.robots.checks import check_motion
from stablemofusion.robots.model import load_robot, mujoco
from stablemofusion.robots.retarget import retarget

HERE = Path(__file__).resolve().parent
SETS = {"freeform": HERE / "prompts_freeform.jsonl", "paths": HERE / "paths" / "heldout.jsonl"}


def prompts_of(name: str, n: int) -> list[str]:
    rows = [json.loads(x)["prompt"] for x in SETS[name].read_text().splitlines() if x.strip()]
    return rows[:n] if n else rows


def pct(values, q) -> float:
    values = np.concatenate([np.ravel(v) for v in values]) if len(values) else np.zeros(1)
    return float(np.percentile(values, q)) if values.size else 0.0


def check(args) -> None:
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    out = {}
    for name in args.robots.split(","):
        robot = load_robot(name)
        for set_name in args.sets.split(","):
            prompts = prompts_of(set_name, args.n)
            rows, seconds = [], 0.0
            for k in range(0, len(prompts), 32):
                for r in pipe(prompts[k:k + 32], seed=args.seed):
                    motion = retarget(robot, r.joints, r.fps, r.contacts)
                    rows.append(check_motion(robot, motion, r.joints, r.fps, r.contacts))
                    seconds += r.seconds
            speeds = np.stack([r["joint_speed_max_rads"] for r in rows])
            out[f"{name}/{set_name}"] = {
                "motions": len(rows), "seconds": round(seconds, 1),
                "limit_violations": sum(r["limit_violations"] for r in rows),
                "self_contact_frames": sum(r["self_contact_frames"] for r in rows),
                "motions_with_self_contact": sum(r["self_contact_frames"] > 0 for r in rows),
                "planted_sole_height_cm_p95_max": [round(100 * pct([r["planted_sole_height_m"] for r in rows], q), 2)
                                                    for q in (95, 100)],
                "planted_frames_over_2cm_share": round(float(np.mean(np.concatenate(
                    [r["planted_sole_height_m"] for r in rows]) > 0.02)), 5),
                "planted_frames_over_2cm_of": [int(sum((r["planted_sole_height_m"] > 0.02).sum() for r in rows)),
                                               int(sum(len(r["planted_sole_height_m"]) for r in rows))],
                "sole_below_floor_cm_max": round(100 * max(r["sole_below_floor_m"] for r in rows), 2),
                "slide_mps_median_p95_robot": [round(pct([r["robot_slide_mps"] for r in rows], q), 3) for q in (50, 95)],
                "slide_mps_median_p95_human_scaled": [round(pct([r["human_slide_mps"] for r in rows], q), 3)
                                                      for q in (50, 95)],
                "tracking_cm_median_p95": [round(100 * pct([r["tracking_error_m"] for r in rows], q), 1)
                                           for q in (50, 95)],
                "joint_speed_rads_p99_of_max": round(float(np.percentile(speeds.max(axis=1), 99)), 1),
                "fastest_joint": robot.joint_names[int(np.argmax(speeds.max(axis=0)))],
            }
            print(json.dumps({f"{name}/{set_name}": out[f"{name}/{set_name}"]}), flush=True)
        # time: a 4 s motion, one thread
        r = pipe("a person walks forward", seconds=4, seed=0)[0]
        gen, ret = [], []
        for _ in range(5):
            t = time.perf_counter()
            r = pipe("a person walks forward", seconds=4, seed=0)[0]
            gen.append(time.perf_counter() - t)
            t = time.perf_counter()
            retarget(robot, r.joints, r.fps, r.contacts)
            ret.append(time.perf_counter() - t)
        out[f"{name}/time_ms"] = {"generate_4s": round(1000 * float(np.median(gen)), 1),
                                  "retarget_4s": round(1000 * float(np.median(ret)), 1)}
        print(json.dumps({f"{name}/time_ms": out[f"{name}/time_ms"]}), flush=True)


def replay(args) -> None:
    """A 10 s walk replayed open loop: the trajectory's joint angles as the actuators' targets (position actuators
    as the model defines them; a motor-driven model gets a PD torque kp (q* - q) - kd q' with kp 200, kd 5, as its
    joints' only controller), the base free, from the first frame's pose, on the scene's floor."""
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    r = pipe("a person walks forward slowly", seconds=10, seed=0)[0]
    for name in args.robots.split(","):
        robot = load_robot(name)
        motion = retarget(robot, r.joints, r.fps, r.contacts)
        m = robot.model
        d = mujoco.MjData(m)
        d.qpos[:] = motion.qpos[0]
        mujoco.mj_forward(m, d)
        joint_of = {int(m.actuator_trnid[a, 0]): a for a in range(m.nu)}
        qadr = [int(m.jnt_qposadr[j]) for j in range(1, m.njnt)]
        dadr = [int(m.jnt_dofadr[j]) for j in range(1, m.njnt)]
        position = bool(m.nu and m.actuator_biastype[0] != 0)
        steps = int(round(1 / (m.opt.timestep * motion.fps)))
        height0, fell_at = float(d.qpos[2]), None
        for t in range(len(motion.qpos)):
            for j in range(1, m.njnt):
                a = joint_of.get(j)
                if a is None:
                    continue
                target = motion.qpos[t, qadr[j - 1]]
                d.ctrl[a] = target if position else np.clip(200 * (target - d.qpos[qadr[j - 1]]) - 5 * d.qvel[dadr[j - 1]],
                                                            *m.actuator_ctrlrange[a])
            for _ in range(steps):
                mujoco.mj_step(m, d)
            if fell_at is None and d.qpos[2] < 0.6 * height0:
                fell_at = t / motion.fps
        print(json.dumps({name: {"seconds": round(motion.seconds, 2), "controller": "position actuators" if position
                                 else "PD torque (kp 200, kd 5)", "upright_whole_time": fell_at is None,
                                 "fell_at_s": fell_at, "base_height_start_end_m": [round(height0, 3),
                                                                                  round(float(d.qpos[2]), 3)],
                                 "base_travel_m": round(float(np.linalg.norm(d.qpos[:2] - motion.qpos[0, :2])), 2),
                                 "trajectory_travel_m": round(float(np.linalg.norm(motion.qpos[-1, :2]
                                                                                   - motion.qpos[0, :2])), 2)}}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("what", nargs="?", default="check", choices=("check", "replay"))
    ap.add_argument("--robots", default="g1,h1")
    ap.add_argument("--sets", default="freeform,paths")
    ap.add_argument("--n", type=int, default=0, help="the first N prompts of each set (0: all)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    (check if args.what == "check" else replay)(args)


if __name__ == "__main__":
    main()
