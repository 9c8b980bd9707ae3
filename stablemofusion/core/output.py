"""Output of a :class:`~stablemofusion.core.result.MotionResult`, the one place motions become files or
HTTP bodies: bytes for each format (the server answers with them), and file writers built on them (the CLI).

Formats (:data:`WRITERS`): ``npy`` (joints and features), ``bvh`` (the rigid body), ``json`` (joints and
metadata), ``glb`` (glTF 2.0 binary: a skinned character with one animation), ``mp4`` / ``gif`` (a rendered
video). A new format is one function decorated with ``@writer("NAME")`` taking (result, stem, meta) and
returning the paths it wrote. With a :class:`Rig` (the user's BVH skeleton and its joint map), each result
is also written on that skeleton as ``NAME_rig.bvh``.
"""

from __future__ import annotations

import io
import re
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import orjson

from .. import __version__
from .errors import SMFError
from ..footskate.cleanup import CLEANUP_CONTACTS
from ..footskate.contacts import kinematic_contacts
from .io import write_bytes
from .limits import OUTPUT_FORMATS
from ..motion.files import rigid_bvh_text, rigid_pose
from .result import MotionResult

JSON_DECIMALS = 5  # joint coordinates in JSON: 0.01 mm
SLUG_CHARS = 48  # characters of the prompt in a file name

Writer = Callable[[MotionResult, Path, dict], list[Path]]
WRITERS: dict[str, Writer] = {}
OUTPUTS: dict[str, Callable[[Path], list[Path]]] = {}  # format -> the paths it writes for a stem


def writer(name: str, *suffixes: str):
    """Register a file writer of format ``name`` writing ``stem + suffix`` for each of ``suffixes``."""

    def register(fn: Writer) -> Writer:
        WRITERS[name] = fn
        OUTPUTS[name] = lambda stem: [stem.with_name(stem.name + s) for s in suffixes]
        return fn

    return register


# --- bytes (HTTP bodies, and what the file writers write) ---

def npy_bytes(result: MotionResult, what: str = "joints") -> bytes:
    """The result's joints (T, J, 3) or features (T, D) as a float32 .npy file."""
    array = {"joints": result.joints, "features": result.features}[what]
    buf = io.BytesIO()
    np.save(buf, np.asarray(array, dtype=np.float32), allow_pickle=False)
    return buf.getvalue()


def _rigid(result: MotionResult):
    """The result's rigid body (the closed-form rigid pose of its joints without one)."""
    return result.motion if result.motion is not None else rigid_pose(result.joints, _skeleton(result))


def bvh_text(result: MotionResult) -> str:
    """The BVH file of the result's rigid body, so the file reads back to ``result.joints``."""
    return rigid_bvh_text(_rigid(result), result.fps)


def bvh_bytes(result: MotionResult) -> bytes:
    return bvh_text(result).encode("utf-8")


def glb_bytes(result: MotionResult, **meta) -> bytes:
    """The result as a binary glTF 2.0 file (pygltflib): named joint nodes with a skin and a capsule body, one
    animation (a rotation per joint, the root's translation) at the result's frame rate; metres, Y up; ``meta``
    (how it was made: :func:`made_by` and the settings) in the file's extras."""
    from ..motion.gltf import rigid_to_glb

    return rigid_to_glb(_rigid(result), result.fps, extras=meta)


def made_by(model_version: str | None) -> dict:
    """What every output's metadata says of what made it: the package's version and the model's (a release's
    name, ``export.version`` of its config; None for a model without one)."""
    return {"smf_version": __version__, "model_version": model_version}


@dataclass(frozen=True)
class Rig:
    """The user's skeleton: a BVH file's rest skeleton (``motion.bvh.BVH``) and the joint map from it to ours."""

    bvh: object
    joint_map: object


def rig_bvh_text(result: MotionResult, rig: Rig) -> str:
    """The result retargeted onto ``rig``: a BVH with the rig's joints, order, names, offsets and channels;
    unmapped joints keep their rest pose; root height and stride scaled to the rig's legs."""
    from ..motion.retarget import retarget_onto_bvh, rig_bvh_text as rig_text

    if result.joints.shape[1:] != (22, 3):
        raise SMFError(f"retargeting onto a rig needs a 22-joint (HumanML3D) motion, got {result.joints.shape[1]} joints")
    return rig_text(rig.bvh, retarget_onto_bvh(result.joints, rig.bvh, rig.joint_map), result.fps)


def planted_feet(joints: np.ndarray, fps: float) -> np.ndarray | None:
    """(T, 4) bool the feet (left ankle, left toe, right ankle, right toe) that the footskate cleanup's detector
    counts as planted in joints (T, 22, 3) metres; None for another skeleton or a single frame."""
    if joints.ndim != 3 or joints.shape[1:] != (22, 3) or len(joints) < 2:
        return None
    return kinematic_contacts(joints, fps, config=CLEANUP_CONTACTS)


def json_payload(result: MotionResult, **meta) -> dict:
    """The JSON object of a result: prompt, fps, frames, seed, ``meta``, the closest known action (models
    with actions.json), the joints (T, J, 3) rounded to :data:`JSON_DECIMALS` and ``contacts``: the frames the
    footskate cleanup held each foot joint, or without a cleanup those its detector counts as planted
    (:func:`planted_feet`), 4 lists (left ankle, left toe, right ankle, right toe) of T 0/1; for a prompt of
    several parts ``sequence``, how it was split (each part's prompt and seconds); ``warnings``, what the user should
    know of how it was made (a prompt out of domain, a length clamped), where there is any; the HTTP response body."""
    held = result.contacts if result.contacts is not None else planted_feet(result.joints, result.fps)
    sequence = [{"prompt": p, "seconds": round(float(s), 3)} for p, s in result.sequence or ()]
    return {"prompt": result.prompt, "fps": result.fps, "frames": result.frames, "seed": result.seed, **meta,
            **(result.domain.to_dict(result.prompt) if result.domain else {}),
            **({"sequence": sequence} if sequence else {}), **({"warnings": result.warnings} if result.warnings else {}),
            **({} if held is None else {"contacts": np.asarray(held, int).T.tolist()}),
            "joints": _rounded(result.joints)}


def json_bytes(result: MotionResult, **meta) -> bytes:
    return _dumps(json_payload(result, **meta))


def joints_json_bytes(joints: np.ndarray, fps: float) -> bytes:
    """Joints (T, J, 3) of a motion read from a file, as the viewer reads them: fps, frames, joints and, for our
    skeleton, the planted feet (``contacts`` as in :func:`json_payload`)."""
    planted = planted_feet(np.asarray(joints, dtype=np.float64), fps)
    return _dumps({"fps": fps, "frames": len(joints), "joints": _rounded(joints),
                   **({} if planted is None else {"contacts": planted.astype(int).T.tolist()})})


def _rounded(joints: np.ndarray) -> np.ndarray:
    """Joints rounded to :data:`JSON_DECIMALS`, in float64 as the standard library's encoder wrote them."""
    return np.ascontiguousarray(np.round(np.asarray(joints, dtype=np.float64), JSON_DECIMALS))  # any memory layout


def _dumps(body: dict) -> bytes:
    """Compact JSON, UTF-8, one line; numpy arrays written directly (orjson: about 8x faster than the standard
    library's encoder on a 4 s motion's joints; the same values). NaN or infinite joints are an error, not
    ``null``."""
    for value in body.values():
        if isinstance(value, np.ndarray) and not np.isfinite(value).all():
            raise SMFError("joints contain NaN or inf: not written as JSON")
    return orjson.dumps(body, option=orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_APPEND_NEWLINE)


# --- files ---

@writer("npy", "_joints.npy", "_features.npy")
def write_npy(result: MotionResult, stem: Path, meta: dict) -> list[Path]:
    joints, features = OUTPUTS["npy"](stem)
    return [write_bytes(joints, npy_bytes(result, "joints")), write_bytes(features, npy_bytes(result, "features"))]


@writer("bvh", ".bvh")
def write_bvh(result: MotionResult, stem: Path, meta: dict) -> list[Path]:
    return [write_bytes(OUTPUTS["bvh"](stem)[0], bvh_bytes(result))]


@writer("json", ".json")
def write_json(result: MotionResult, stem: Path, meta: dict) -> list[Path]:
    return [write_bytes(OUTPUTS["json"](stem)[0], json_bytes(result, **meta))]


@writer("glb", ".glb")
def write_glb(result: MotionResult, stem: Path, meta: dict) -> list[Path]:
    return [write_bytes(OUTPUTS["glb"](stem)[0], glb_bytes(result, **meta))]


RIG_SUFFIX = "_rig.bvh"


def write_rig(result: MotionResult, stem: Path, rig: Rig) -> Path:
    return write_bytes(stem.with_name(stem.name + RIG_SUFFIX), rig_bvh_text(result, rig).encode("utf-8"))


def _video(fmt: str) -> Writer:
    def write_video(result: MotionResult, stem: Path, meta: dict) -> list[Path]:
        from ..render import render_video

        return [render_video(result.joints, OUTPUTS[fmt](stem)[0], skeleton=_skeleton(result), fps=result.fps,
                             title=result.prompt)]

    return writer(fmt, "." + fmt)(write_video)


_video("mp4")
_video("gif")
FORMATS = tuple(WRITERS)
assert set(FORMATS) == set(OUTPUT_FORMATS), "limits.OUTPUT_FORMATS names every writer"


def parse_formats(text: str) -> list[str]:
    """A comma list of formats, checked: ``"npy,bvh"`` -> ["npy", "bvh"]."""
    formats = [f.strip().lower() for f in text.split(",") if f.strip()]
    bad = [f for f in formats if f not in WRITERS]
    if bad or not formats:
        raise SMFError(f"unknown format(s) {bad or text!r}; choose from {', '.join(WRITERS)}")
    from ..render.encoders import check_encoder

    for f in formats:
        check_encoder(f)
    return formats


def slug(text: str, index: int) -> str:
    """A file name stem from a prompt: ``000_a_person_walks``; letters of any script kept (``001_一个人向前走``), at
    most SLUG_CHARS characters cut at a word's end."""
    words = re.sub(r"[\W_]+", "_", unicodedata.normalize("NFC", text).lower()).strip("_")
    if len(words) > SLUG_CHARS:
        cut = words[:SLUG_CHARS + 1].rfind("_")
        words = words[:cut if cut > 0 else SLUG_CHARS].rstrip("_")
    return f"{index:03d}_{words or 'motion'}"


def free_stem(stem: Path, formats: list[str], overwrite: bool = False, rig: bool = False) -> Path:
    """``stem``, or ``stem-2``, ``stem-3``, ... the first whose files (for ``formats``, and the rig's BVH with
    ``rig``) do not exist yet: outputs are never overwritten silently (``overwrite`` True: ``stem`` as it is)."""
    def paths(c: Path) -> list[Path]:
        return [p for f in formats for p in OUTPUTS[f](c)] + ([c.with_name(c.name + RIG_SUFFIX)] if rig else [])

    candidate, n = stem, 1
    while not overwrite and any(p.exists() for p in paths(candidate)):
        n += 1
        candidate = stem.with_name(f"{stem.name}-{n}")
    return candidate


def write_result(result: MotionResult, stem: Path, formats: list[str], meta: dict | None = None,
                 rig: Rig | None = None) -> list[Path]:
    """Write ``result`` in each of ``formats`` beside ``stem`` (atomically), and on ``rig`` when given; returns
    the paths written."""
    paths = [p for f in formats for p in WRITERS[f](result, Path(stem), dict(meta or {}))]
    return paths + ([write_rig(result, Path(stem), rig)] if rig is not None else [])


def write_results(results: list[MotionResult], out: Path, formats: list[str], meta: dict | None = None, *,
                  overwrite: bool = False, rig: Rig | None = None, first: int = 0) -> list[Path]:
    """Write each result named from its prompt and number (``out/000_prompt.*``, counted from ``first``; a free
    name unless ``overwrite``); prints one line per motion; returns the stems."""
    stems = []
    for i, r in enumerate(results, first):
        stem = free_stem(Path(out) / slug(r.prompt, i), formats, overwrite, rig is not None)
        write_result(r, stem, formats, meta, rig)
        print(f"wrote {stem}.* ({r.frames} frames, {r.seconds:.1f} s, seed {r.seed})")
        stems.append(stem)
    return stems


def _skeleton(result: MotionResult) -> str:
    """The skeleton of a result: its rigid body's, else the one with its number of joints."""
    from ..motion.skeleton import skeleton_for_shape

    return result.motion.skeleton if result.motion is not None else skeleton_for_shape(result.joints.shape)[0].name
