"""The add-on's work, apart from its UI: get a motion (in-process or from `smf serve`), build the selected
armature's rig, retarget with the package's own math (``rig.py``: stablemofusion/motion/rig.py, which `smf
addon` puts in the zip) and write the keys. Blender is Z up; our motions are Y up: a vector (x, y, z) of ours is (x, -z, y) here."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np

from . import rig as rigmath

# Y up (ours) -> Z up (Blender): v_blender = C @ v_ours
C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
MAPS = Path(__file__).resolve().parent / "joint_maps"
LAST_JOINTS = None  # the joints (T, 22, 3) of the last motion made, Y up (for scripts and tests)

# our skeleton (HumanML3D's 22 joints; stablemofusion/motion/skeleton.py, a test keeps them equal)
JOINT_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle", "right_ankle",
    "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
)
PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)


class MotionError(Exception):
    """A motion could not be made or applied (shown in Blender's status bar)."""


_PIPELINES: dict = {}  # the portable pipelines, each model loaded once per Blender session


LAST_WARNINGS: list[str] = []  # the last motion's warnings (not English, out of domain, ...), shown in the panel


def local_pipeline(packages: str = "", required: bool = False, model: str = ""):
    """The pipeline on the ONNX backend (ONNX Runtime: no torch) in Blender's Python, its
    packages found where Blender finds its own or in the ``packages`` folder (a site-packages folder of a runtime
    install made with Blender's Python version; its .pth files are read), of the graphs folder ``model`` (empty:
    the shipped model). None when it is not importable, or with ``required`` a MotionError saying what to
    install."""
    import site
    import sys

    if packages and packages not in sys.path:
        site.addsitedir(packages)  # after Blender's own folders: Blender's numpy stays the one imported
    if model not in _PIPELINES:
        try:
            from stablemofusion.pipelines.motion_pipeline import MotionPipeline
        except ImportError as e:
            if not required:
                return None
            v = sys.version_info
            raise MotionError(f"the stablemofusion runtime is not importable in Blender's Python ({e.name or e} is "
                              f"missing): install it for Python {v.major}.{v.minor} and set the add-on's Python "
                              "packages folder (docs/character.md)") from None
        try:
            _PIPELINES[model] = MotionPipeline.from_pretrained(model or None, backend="onnx", threads=1)
        except Exception as e:  # noqa: BLE001 - the package's one-line errors (a folder without graphs)
            raise MotionError(str(e)) from None
    return _PIPELINES[model]


def generate_joints(prompt: str, seconds: float | None, seed: int, server: str, backend: str = "AUTO", packages: str = "",
                    model: str = "") -> tuple[np.ndarray, float, str]:
    """(joints (T, 22, 3) metres Y up, fps, where it came from): in Blender's Python on the portable runtime when it
    is importable (``backend`` AUTO or LOCAL; ``packages`` a folder to find it in; ``model`` a graphs folder, empty:
    the shipped model), else from a running `smf serve` at ``server``; ``seconds`` None: the length the model
    predicts from the prompt."""
    global LAST_WARNINGS
    if backend in ("AUTO", "LOCAL"):
        pipe = local_pipeline(packages, required=backend == "LOCAL", model=model)
        if pipe is not None:
            try:
                r = pipe([prompt], seconds=seconds, seed=seed)[0]
            except Exception as e:  # noqa: BLE001 - the package's one-line errors (SMFError) and any other
                raise MotionError(str(e)) from None
            LAST_WARNINGS = list(r.warnings)
            return np.asarray(r.joints, np.float64), float(r.fps), "in Blender"
    body = json.dumps({"prompt": prompt, "seed": seed, **({} if seconds is None else {"seconds": seconds})}).encode()
    url = server.rstrip("/") + "/v1/generate"
    req = urllib.request.Request(url, data=body, headers={"Content-Type": "application/json"}, method="POST")
    try:
        with urllib.request.urlopen(req, timeout=300) as resp:
            data = json.loads(resp.read())
    except urllib.error.HTTPError as e:
        try:
            msg = json.loads(e.read()).get("error", str(e))
        except Exception:  # noqa: BLE001 - any unreadable error body
            msg = str(e)
        raise MotionError(f"{url}: {msg}") from None
    except (urllib.error.URLError, OSError) as e:
        local = ("" if backend == "SERVER" else " or let it run in Blender: set the add-on's Python packages folder to a "
                 "site-packages folder holding stablemofusion (docs/character.md)")
        raise MotionError(f"no stablemofusion server at {server} ({e}); start one with `smf serve`{local}") from None
    LAST_WARNINGS = [str(w) for w in data.get("warnings", [])]
    return np.asarray(data["joints"], np.float64), float(data["fps"]), url


def load_map(name: str) -> dict:
    return json.loads((MAPS / f"{name}.json").read_text(encoding="utf-8"))["joints"]


def choose_map(bone_names: list[str]) -> tuple[str, list[tuple[str, ...]]]:
    """(name, per joint of ours the source names) of the first bundled joint map whose joints the armature
    has (Mixamo, Bandai-Namco, ours); 'mixamorig1:'-style prefixes are matched too."""
    names = set(bone_names)
    for path in sorted(MAPS.glob("*.json")):
        joints = load_map(path.stem)
        sources = [tuple([s] if isinstance(s, str) else s) for s in (joints[n] for n in JOINT_NAMES)]
        prefixes = {""}
        if path.stem == "mixamo":
            prefixes |= {n.split(":")[0] + ":" for n in bone_names if ":" in n}
        for prefix in prefixes:
            renamed = [tuple(prefix + s.split(":")[-1] if path.stem == "mixamo" else s for s in src) for src in sources]
            if all(s in names for src in renamed for s in src):
                return path.stem, renamed
    raise MotionError("the selected armature matches no bundled joint map (mixamo, bandai-namco, humanml3d)")


def _bone_order(arm) -> list:
    """The armature's bones with every parent before its children."""
    order, stack = [], [b for b in arm.data.bones if b.parent is None][::-1]
    while stack:
        b = stack.pop()
        order.append(b)
        stack.extend(list(b.children)[::-1])
    return order


def armature_rig(arm) -> tuple[rigmath.Rig, list]:
    """The armature's rest skeleton as a rig (bone heads in world space, metres, Y up) under a virtual root at
    the origin, and its bones in rig order (index j + 1 in the rig)."""
    bones = _bone_order(arm)
    mw = np.array(arm.matrix_world)
    heads = np.array([(mw @ np.append(np.array(b.head_local), 1.0))[:3] for b in bones]) @ C  # C^T v, row-wise
    index = {b.name: i + 1 for i, b in enumerate(bones)}
    parents = [-1] + [index[b.parent.name] if b.parent else 0 for b in bones]
    pos = np.concatenate([np.zeros((1, 3)), heads])
    offsets = pos - np.concatenate([[np.zeros(3)], pos[[p for p in parents[1:]]]])
    offsets[0] = 0.0
    return rigmath.Rig(["__origin__"] + [b.name for b in bones], np.array(parents), offsets), bones


def _quat(m: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations -> (N, 4) unit quaternions (w, x, y, z), w >= 0 on a tie-free branch per matrix."""
    out = np.empty((len(m), 4))
    for i, r in enumerate(m):
        tr = np.trace(r)
        if tr > 0:
            s = np.sqrt(tr + 1.0) * 2
            out[i] = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
        else:
            k = int(np.argmax(np.diag(r)))
            a, b = (k + 1) % 3, (k + 2) % 3
            s = np.sqrt(1.0 + r[k, k] - r[a, a] - r[b, b]) * 2
            q = np.empty(4)
            q[0] = (r[b, a] - r[a, b]) / s
            q[1 + k] = 0.25 * s
            q[1 + a] = (r[a, k] + r[k, a]) / s
            q[1 + b] = (r[b, k] + r[k, b]) / s
            out[i] = q
    for i in range(1, len(out)):  # keys in one hemisphere, so Blender interpolates the short way
        if out[i] @ out[i - 1] < 0:
            out[i] = -out[i]
    return out


def apply_motion(arm, joints: np.ndarray, fps: float, action_name: str = "stablemofusion") -> str:
    """Retarget joints (T, 22, 3) onto armature object ``arm`` and key its pose bones (frames 1..T) in a new
    action (the one an earlier generation made on it, emptied and renamed: no orphan action is left behind);
    returns the joint map's name."""
    import bpy

    map_name, sources = choose_map([b.name for b in arm.data.bones])
    rig, bones = armature_rig(arm)
    targets = rigmath.targets_from_sources(rig.names, sources)
    try:
        motion = rigmath.retarget(joints, rig, targets)
    except rigmath.SMFError as e:
        raise MotionError(str(e)) from None
    T = len(joints)
    w = np.array(arm.matrix_world)[:3, :3]
    w = w / np.cbrt(abs(np.linalg.det(w)))  # its rotation (uniform scale removed)
    to_arm = w.T @ C  # ours (world, Y up) -> armature space
    mw_inv = np.linalg.inv(np.array(arm.matrix_world))
    arm.animation_data_create()
    action = arm.animation_data.action
    if action is not None and action.get("stablemofusion"):  # an earlier generation's: reused, not left behind
        action.fcurves.clear()
        action.name = action_name
    else:
        action = bpy.data.actions.new(action_name)
        action["stablemofusion"] = True
        arm.animation_data.action = action
    pelvis = int(np.flatnonzero(targets == rigmath.PELVIS)[0])
    positions = motion.positions(rig.parents)
    frames = np.arange(1, T + 1, dtype=np.float64)

    def key(path: str, values: np.ndarray, group: str) -> None:
        for i in range(values.shape[1]):
            fc = action.fcurves.new(path, index=i, action_group=group)
            fc.keyframe_points.add(T)
            fc.keyframe_points.foreach_set("co", np.stack([frames, values[:, i]], -1).ravel())
            fc.update()

    for j, bone in enumerate(bones, 1):
        pb = arm.pose.bones[bone.name]
        pb.rotation_mode = "QUATERNION"
        pb.location = (0, 0, 0)
        pb.rotation_quaternion = (1, 0, 0, 0)
        if targets[j] < 0 and j != pelvis:
            continue
        b = np.array(bone.matrix_local)[:3, :3]
        b = b / np.linalg.norm(b, axis=0)
        local = to_arm @ motion.rotations[:, j] @ to_arm.T  # the rotation relative to the parent, armature axes
        basis = b.T @ local @ b
        key(f'pose.bones["{bone.name}"].rotation_quaternion', _quat(basis), bone.name)
        if j == pelvis:
            world = positions[:, j] @ C.T  # Blender world
            in_arm = (mw_inv[:3, :3] @ world.T).T + mw_inv[:3, 3]
            key(f'pose.bones["{bone.name}"].location', (in_arm - np.array(bone.head_local)) @ b, bone.name)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = max(1, int(round(fps))), max(1, int(round(fps))) / fps
    scene.frame_start, scene.frame_end = 1, T
    return map_name


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def create_our_armature(joints: np.ndarray, name: str = "stablemofusion"):
    """A new armature object with our 22 joints as bones, in our rest pose, facing +Z: each bone along our rest
    direction (stablemofusion/motion/skeleton.py) with its mean length over the motion, except the children of the
    branching joints (pelvis, upper spine), which sit where they sit in the motion around their joint (its frame:
    X from the right child to the left one, Y towards the third), so that the armature can take the motion's
    every pose exactly."""
    import bpy

    X = np.asarray(joints, np.float64)
    dirs = np.array(REST_DIRECTIONS)
    lengths = np.array([0.0] + [np.linalg.norm(X[:, j] - X[:, p], axis=-1).mean() for j, p in enumerate(PARENTS) if p >= 0])
    kids = {j: [c for c, p in enumerate(PARENTS) if p == j] for j in range(22)}
    local = {}  # child of a branching joint -> its mean offset in the joint's frame
    for b, ch in kids.items():
        if len(ch) < 2:
            continue
        side = sorted(ch, key=lambda c: dirs[c][0])  # -X child, then the one straight up or down, then +X
        x = _unit(X[:, side[-1]] - X[:, side[0]])
        y = (X[:, side[1]] - X[:, b]) * np.sign(dirs[side[1]][1])
        y = _unit(y - (y * x).sum(-1, keepdims=True) * x)
        frame = np.stack([x, y, np.cross(x, y)], -1)  # (T, 3, 3) columns x, y, z
        for c in ch:
            local[c] = np.einsum("tij,ti->j", frame, X[:, c] - X[:, b]) / len(X)
    rest = np.zeros((22, 3))
    rest[0] = [0.0, X[:, 0, 1].mean(), 0.0]
    for j, p in enumerate(PARENTS):
        if p >= 0:
            rest[j] = rest[p] + (local[j] if j in local else dirs[j] * lengths[j])
    data = bpy.data.armatures.new(name)
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT")
    for j, n in enumerate(JOINT_NAMES):
        eb = data.edit_bones.new(n)
        head = rest[j] @ C.T
        tail = (rest[kids[j]].mean(0) if len(kids[j]) == 1 else rest[j] + dirs[j] * 0.08 if not kids[j]
                else rest[j] + np.array([0.0, 0.1, 0.0])) @ C.T
        if np.linalg.norm(tail - head) < 1e-3:
            tail = head + np.array([0.0, 0.0, 0.05])
        eb.head, eb.tail = head.tolist(), tail.tolist()
        if PARENTS[j] >= 0:
            eb.parent = data.edit_bones[JOINT_NAMES[PARENTS[j]]]
    bpy.ops.object.mode_set(mode="OBJECT")
    add_body(obj)
    return obj


def add_body(arm) -> list:
    """A simple body for an armature the add-on made, so that a render shows the character: a tapered cylinder
    along each bone from its parent's joint to its own (a sphere for the head), each parented to the parent bone
    (rigid skinning), one grey material. Returns the body's objects (children of ``arm``)."""
    import bmesh
    import bpy
    from mathutils import Matrix

    material = bpy.data.materials.get("stablemofusion body") or bpy.data.materials.new("stablemofusion body")
    material.diffuse_color = (0.72, 0.72, 0.75, 1.0)
    made = []
    for bone in arm.data.bones:
        head = bone.name == "head"
        length = bone.length
        if length < 0.02 and not head:
            continue
        bm = bmesh.new()
        if head:
            bmesh.ops.create_uvsphere(bm, u_segments=16, v_segments=10, radius=BODY_RADIUS["head"])
            bmesh.ops.translate(bm, verts=bm.verts, vec=(0.0, 0.04, 0.0))
        else:
            r = BODY_RADIUS.get(bone.name, BODY_RADIUS["limb"])
            bmesh.ops.create_cone(bm, cap_ends=True, segments=12, radius1=r, radius2=0.8 * r, depth=length)
            bmesh.ops.rotate(bm, verts=bm.verts, cent=(0, 0, 0), matrix=Matrix.Rotation(-np.pi / 2, 3, "X"))  # Z->Y
            bmesh.ops.translate(bm, verts=bm.verts, vec=(0.0, length / 2, 0.0))
        mesh = bpy.data.meshes.new(f"{arm.name} {bone.name}")
        bm.to_mesh(mesh)
        bm.free()
        mesh.materials.append(material)
        part = bpy.data.objects.new(mesh.name, mesh)
        bpy.context.scene.collection.objects.link(part)
        part.parent, part.parent_type, part.parent_bone = arm, "BONE", bone.name
        part.location = (0.0, -length, 0.0)  # a bone's child sits at its tail: moved back to its head
        made.append(part)
    return made


BODY_RADIUS = {"head": 0.1, "limb": 0.045, "pelvis": 0.12, "spine1": 0.11, "spine2": 0.12, "spine3": 0.12, "neck": 0.05,
               "left_hip": 0.07, "right_hip": 0.07, "left_knee": 0.065, "right_knee": 0.065, "left_collar": 0.05,
               "right_collar": 0.05, "left_foot": 0.035, "right_foot": 0.035, "left_ankle": 0.05, "right_ankle": 0.05}


REST_DIRECTIONS = (
    (0, 0, 0), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, -1, 0), (0, 1, 0), (0, -1, 0), (0, -1, 0), (0, 1, 0),
    (0, 0, 1), (0, 0, 1), (0, 1, 0), (1, 0, 0), (-1, 0, 0), (0, 0, 1), (0, -1, 0), (0, -1, 0), (0, -1, 0), (0, -1, 0),
    (0, -1, 0), (0, -1, 0),
)
