"""Test helpers for .glb files: an independent reader that plays the animation through the node tree, and
where the external tools (Khronos glTF validator on node, Blender) are."""

from __future__ import annotations

import json
import os
import shutil
import struct
from pathlib import Path

import numpy as np

_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def read_glb(path: Path) -> tuple[dict, bytes]:
    """(JSON document, BIN chunk) of a .glb file, parsed from the byte layout of the glTF 2.0 spec."""
    data = Path(path).read_bytes()
    magic, version, length = struct.unpack_from("<III", data, 0)
    assert magic == 0x46546C67 and version == 2 and length == len(data)
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A
    doc = json.loads(data[20:20 + json_len])
    bin_len, bin_type = struct.unpack_from("<II", data, 20 + json_len)
    assert bin_type == 0x004E4942
    return doc, data[28 + json_len:28 + json_len + bin_len]


def accessor(doc: dict, blob: bytes, index: int) -> np.ndarray:
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    n = _SIZES[acc["type"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    arr = np.frombuffer(blob, dtype=_DTYPES[acc["componentType"]], count=acc["count"] * n, offset=start)
    return arr.reshape(acc["count"], n) if n > 1 else arr


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) glTF quaternions (x, y, z, w) -> (..., 3, 3)."""
    x, y, z, w = np.moveaxis(np.asarray(q, np.float64), -1, 0)
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).reshape(
        q.shape[:-1] + (3, 3))


def play_node_tree(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(node names, key times (T,), world positions (T, N, 3) of every node) of the file's first animation,
    evaluated at its keys through the scene's node hierarchy (TRS; scale taken as 1)."""
    doc, blob = read_glb(path)
    nodes = doc["nodes"]
    anim = doc["animations"][0]
    times = None
    trans = {i: np.asarray(n.get("translation", [0, 0, 0]), np.float64) for i, n in enumerate(nodes)}
    rots = {i: np.asarray(n.get("rotation", [0, 0, 0, 1]), np.float64) for i, n in enumerate(nodes)}
    for ch in anim["channels"]:
        s = anim["samplers"][ch["sampler"]]
        t = accessor(doc, blob, s["input"]).astype(np.float64)
        times = t if times is None else times
        assert np.array_equal(t, times)
        out = accessor(doc, blob, s["output"]).astype(np.float64)
        node, kind = ch["target"]["node"], ch["target"]["path"]
        (trans if kind == "translation" else rots)[node] = out
    T = len(times)
    N = len(nodes)
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}
    pos = np.zeros((T, N, 3))
    glob = np.zeros((T, N, 3, 3))
    done: set[int] = set()

    def visit(i: int) -> None:
        if i in done:
            return
        t = np.broadcast_to(trans[i], (T, 3))
        r = quat_matrix(np.broadcast_to(rots[i], (T, 4)))
        if i in parent:
            p = parent[i]
            visit(p)
            pos[:, i] = pos[:, p] + np.einsum("tij,tj->ti", glob[:, p], t)
            glob[:, i] = glob[:, p] @ r
        else:
            pos[:, i], glob[:, i] = t, r
        done.add(i)

    for i in range(N):
        visit(i)
    return [n.get("name", "") for n in nodes], times, pos


def gltf_validator_dir() -> Path | None:
    """The folder holding node_modules/gltf-validator ($SMF_TOOLS, else ~/.cache/stablemofusion-tools, where
    .ci/run installs it), or None when node or the package is absent."""
    folder = Path(os.environ.get("SMF_TOOLS", Path.home() / ".cache" / "stablemofusion-tools"))
    if shutil.which("node") and (folder / "node_modules" / "gltf-validator" / "package.json").is_file():
        return folder
    return None


# node VALIDATE_JS FILE.glb PACKAGE_DIR -> the validator's issues as JSON (a .cjs script: require by path)
VALIDATE_JS = """
const fs = require('fs');
const validator = require(process.argv[3]);
validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2])), {maxIssues: 200})
  .then(report => console.log(JSON.stringify(report.issues)))
  .catch(err => { console.error(String(err)); process.exit(1); });
"""
