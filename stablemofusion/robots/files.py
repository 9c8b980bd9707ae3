"""A robot trajectory written the way robotics users load it: ``.npz`` (arrays by name), ``.csv`` (one named column
per coordinate), an MJCF keyframe file MuJoCo opens, and a video from MuJoCo's offscreen renderer."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from ..core.io import write_bytes, write_text
from ..render.video import write_frames
from .model import Robot, mujoco
from .retarget import RobotMotion

ROBOT_FORMATS = ("npz", "csv", "xml", "mp4", "gif")


def csv_columns(motion: RobotMotion) -> list[str]:
    """The CSV's columns: time, the base position (m) and quaternion (w x y z), then each joint (rad) by name."""
    return ["time", "base_x", "base_y", "base_z", "base_qw", "base_qx", "base_qy", "base_qz", *motion.joint_names]


def npz_arrays(motion: RobotMotion, meta: dict | None = None) -> dict[str, np.ndarray]:
    """The ``.npz`` arrays: ``qpos`` (T, nq) in MuJoCo's order; ``root_pos`` (T, 3); ``root_rot`` (T, 4) x y z w
    (the order of the community's retargeted datasets) and ``root_quat_wxyz`` (MuJoCo's); ``dof_pos`` (T, J);
    ``joint_names``; ``fps``; ``planted`` (T, 2) the human's left and right foot standing; ``meta`` (JSON)."""
    return {"qpos": motion.qpos, "root_pos": motion.root_pos, "root_rot": motion.root_quat[:, [1, 2, 3, 0]],
            "root_quat_wxyz": motion.root_quat, "dof_pos": motion.dof_pos,
            "joint_names": np.array(motion.joint_names), "fps": np.array(motion.fps), "planted": motion.planted,
            "robot": np.array(motion.robot), "scale": np.array(motion.scale),
            "meta": np.array(json.dumps({"warnings": motion.warnings, **(meta or {})}))}


def json_payload(motion: RobotMotion) -> dict:
    """The trajectory as JSON: robot, fps, ``columns`` (as the CSV's, without time), ``qpos`` rows in that order,
    ``planted``, ``scale``, ``warnings``."""
    return {"robot": motion.robot, "fps": motion.fps, "frames": len(motion.qpos), "columns": csv_columns(motion)[1:],
            "qpos": np.round(motion.qpos, 6), "planted": motion.planted.astype(int).T.tolist(),
            "scale": round(motion.scale, 6), "warnings": list(motion.warnings)}


def write_npz(motion: RobotMotion, path: str | Path, meta: dict | None = None) -> Path:
    buf = io.BytesIO()
    np.savez(buf, **npz_arrays(motion, meta))
    return write_bytes(path, buf.getvalue())


def write_csv(motion: RobotMotion, path: str | Path) -> Path:
    times = np.arange(len(motion.qpos)) / motion.fps
    rows = [",".join(csv_columns(motion))]
    rows += [",".join(f"{v:.6f}" for v in (t, *q)) for t, q in zip(times, motion.qpos)]
    write_text(path, "\n".join(rows) + "\n")
    return Path(path)


def write_keyframes(motion: RobotMotion, robot: Robot, path: str | Path) -> Path:
    """The robot's MJCF (its scene, floor included) with every frame as a keyframe (``time`` and ``qpos``), its
    meshes read from the robot's folder: open it in MuJoCo's viewer (``python -m mujoco.viewer --mjcf FILE``) and
    step through the keys."""
    spec = mujoco.MjSpec.from_file(str(robot.path))
    spec.meshdir = str((robot.path.parent / (spec.meshdir or ".")).resolve())
    for t, q in enumerate(motion.qpos):
        spec.add_key(name=f"f{t:05d}", time=t / motion.fps, qpos=q.tolist())
    write_text(path, spec.to_xml())
    return Path(path)


def render_frames(robot: Robot, qpos: np.ndarray, size: tuple[int, int] = (360, 480), every: int = 1):
    """Yields (H, W, 3) uint8 frames of the robot in each pose, from MuJoCo's offscreen renderer, a camera
    following the base from the front left."""
    m = robot.model
    d = mujoco.MjData(m)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.distance, cam.azimuth, cam.elevation = 3.2, 150.0, -15.0
    with mujoco.Renderer(m, *size) as renderer:
        for t in range(0, len(qpos), every):
            d.qpos[:] = qpos[t]
            mujoco.mj_forward(m, d)
            cam.lookat[:] = [qpos[t, 0], qpos[t, 1], 0.6 * robot.model.qpos0[2] + 0.1]
            renderer.update_scene(d, camera=cam)
            yield renderer.render().copy()


def write_video(motion: RobotMotion, robot: Robot, path: str | Path, fps: float = 25.0) -> Path:
    """The trajectory rendered by MuJoCo to ``path`` (.mp4 or .gif) at about ``fps``."""
    every = max(1, round(motion.fps / fps))
    return write_frames(render_frames(robot, motion.qpos, every=every), path, motion.fps / every)


def write_robot(motion: RobotMotion, robot: Robot, stem: Path, formats: list[str],
                meta: dict | None = None) -> list[Path]:
    """Each of ``formats`` (``ROBOT_FORMATS``) beside ``stem``, named ``<stem>.<robot>.<suffix>``."""
    out = []
    for f in formats:
        path = stem.with_name(f"{stem.name}.{motion.robot}.{f}")
        out.append({"npz": lambda: write_npz(motion, path, meta), "csv": lambda: write_csv(motion, path),
                    "xml": lambda: write_keyframes(motion, robot, path),
                    "mp4": lambda: write_video(motion, robot, path), "gif": lambda: write_video(motion, robot, path)}[f]())
    return out
