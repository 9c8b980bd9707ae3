"""OUTPUT FORMATTING of the server, in one place: one function per format (a generated motion as JSON joints,
a BVH file or a joints .npy; a converted upload as JSON joints). The package's output module replaces these
when it lands; nothing else in serve/ formats a motion."""

from __future__ import annotations

import io
import json

import numpy as np
from fastapi.responses import Response

JOINT_DECIMALS = 5


def json_motion(result, seed: int) -> Response:
    """A generated motion as JSON: prompt, fps, frames, seed, the domain check and the joints (metres)."""
    body = {"prompt": result.prompt, "fps": result.fps, "frames": len(result.joints), "seed": seed,
            **(result.domain.to_dict(result.prompt) if result.domain else {}),
            "joints": np.round(result.joints, JOINT_DECIMALS).tolist()}
    # json.dumps (C): FastAPI's own encoder walks every float in Python on the event loop
    return Response(_dumps(body), media_type="application/json")


def bvh_motion(result, seed: int) -> Response:
    """The BVH file of a result's rigid body (as `smf generate` writes it)."""
    from ..motion.files import rigid_bvh_text, rigid_pose

    text = rigid_bvh_text(result.motion if result.motion is not None else rigid_pose(result.joints), result.fps)
    return Response(text, media_type="text/plain; charset=utf-8",
                    headers={"Content-Disposition": 'attachment; filename="motion.bvh"'})


def npy_motion(result, seed: int) -> Response:
    """The joints as a float32 .npy (T, 22, 3)."""
    buf = io.BytesIO()
    np.save(buf, result.joints.astype(np.float32), allow_pickle=False)
    return Response(buf.getvalue(), media_type="application/octet-stream",
                    headers={"Content-Disposition": 'attachment; filename="motion_joints.npy"'})


MOTION_FORMATS = {"json": json_motion, "bvh": bvh_motion, "npy": npy_motion}


def json_joints(fps: float, joints: np.ndarray) -> bytes:
    """An uploaded motion as the viewer reads it: fps, frames, joints."""
    body = {"fps": fps, "frames": len(joints), "joints": np.round(joints, JOINT_DECIMALS).tolist()}
    return _dumps(body)


def _dumps(body: dict) -> bytes:
    return json.dumps(body, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode("utf-8")
