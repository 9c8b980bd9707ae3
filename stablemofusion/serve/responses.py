"""HTTP responses of motions: the bytes come from the package's output module (:mod:`stablemofusion.core.output`,
the one place motions are formatted); this only names each format's media type and download name."""

from __future__ import annotations

from fastapi.responses import Response

from ..core import output
from ..robots.files import json_payload
from ..robots.model import load_robot
from ..robots.retarget import retarget

# format -> (bytes of a result, media type, download file name or None)
MOTION_FORMATS = {
    "json": (output.json_bytes, "application/json", None),
    "bvh": (output.bvh_bytes, "text/plain; charset=utf-8", "motion.bvh"),
    "npy": (output.npy_bytes, "application/octet-stream", "motion_joints.npy"),
    "glb": (output.glb_bytes, "model/gltf-binary", "motion.glb"),
}


def motion_response(result, format: str, meta: dict | None = None) -> Response:
    """A generated motion in ``format`` (a key of :data:`MOTION_FORMATS`); ``meta`` (what made it,
    :func:`~stablemofusion.core.output.made_by`) in the formats that carry metadata (JSON, glb)."""
    encode, media, filename = MOTION_FORMATS[format]
    headers = {"Content-Disposition": f'attachment; filename="{filename}"'} if filename else None
    body = encode(result, **(meta or {})) if format in ("json", "glb") else encode(result)
    return Response(body, media_type=media, headers=headers)


def robot_response(result, robot: str, meta: dict | None = None) -> Response:
    """A generated motion retargeted to a shipped robot (``robot``): its trajectory as JSON (``robot``, ``fps``,
    ``columns``, ``qpos``...), with the motion's prompt, seed, warnings and ``meta``."""
    motion = retarget(load_robot(robot), result.joints, result.fps, result.contacts)
    body = {"prompt": result.prompt, "seed": result.seed, **json_payload(motion), **(meta or {})}
    body["warnings"] = list(result.warnings) + body["warnings"]
    return Response(output._dumps(body), media_type="application/json")
