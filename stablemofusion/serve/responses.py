"""HTTP responses of motions: the bytes come from the package's output module (:mod:`stablemofusion.core.output`,
the one place motions are formatted); this only names each format's media type and download name."""

from __future__ import annotations

from fastapi.responses import Response

from ..core import output

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
