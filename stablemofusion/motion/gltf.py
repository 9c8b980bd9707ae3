"""glTF 2.0 binary (.glb) export of a :class:`~stablemofusion.motion.rigid.RigidMotion`.

The file holds one scene: the skeleton as a tree of nodes named after our joints (each node's translation is
its rest offset, metres, Y up), a skin over those nodes, a simple body (one capsule per bone, a sphere for
the head, each rigidly bound to the joint that carries it) and one animation: a rotation per joint and the
root's translation, one key per frame at the motion's frame rate (linear interpolation).

The container is written with pygltflib (https://pypi.org/project/pygltflib/); the geometry and the keys are
plain numpy arrays packed into the single binary buffer.

Node convention (glTF's): a node's world transform is parent_world @ T(translation) @ R(rotation), so with
translation = offsets[j] and rotation = rotations[t, j] the node tree is exactly the rigid body's forward
kinematics (see :mod:`stablemofusion.motion.rigid`).
"""

from __future__ import annotations

import numpy as np

from ..core.errors import SMFError
from .kinematics import forward_kinematics
from .rigid import RigidMotion
from .rotation import matrix_to_quat
from .skeleton import get_skeleton

# bone radii (m) of the body's capsules, by the joint a bone ends at (HumanML3D names); others get DEFAULT_RADIUS
BONE_RADIUS = {
    "left_hip": 0.075, "right_hip": 0.075, "spine1": 0.10, "spine2": 0.105, "spine3": 0.11,
    "left_knee": 0.065, "right_knee": 0.065, "left_ankle": 0.048, "right_ankle": 0.048,
    "left_foot": 0.038, "right_foot": 0.038, "neck": 0.05, "head": 0.05,
    "left_collar": 0.055, "right_collar": 0.055, "left_shoulder": 0.055, "right_shoulder": 0.055,
    "left_elbow": 0.045, "right_elbow": 0.045, "left_wrist": 0.038, "right_wrist": 0.038,
}
DEFAULT_RADIUS = 0.04
HEAD_RADIUS = 0.1  # sphere around a leaf joint named "head"
HAND_LENGTH = 0.09  # capsule beyond each leaf wrist, along its forearm
BODY_COLOUR = (0.55, 0.62, 0.75, 1.0)

_FLOAT, _UBYTE, _USHORT, _UINT = 5126, 5121, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


def _capsule(a: np.ndarray, b: np.ndarray, radius: float, rings: int = 4, sides: int = 10
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A capsule around segment a -> b (3,) metres: (V, 3) positions, (V, 3) unit normals, (F, 3) triangles.
    A UV sphere split at its equator, the halves moved to a and b (a sphere when a == b)."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    y = axis / length if length > 1e-9 else np.array([0.0, 1.0, 0.0])
    helper = np.eye(3)[np.argmin(np.abs(y))]
    x = np.cross(helper, y)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    # latitudes from the bottom pole (-90 deg) to the top (+90), the equator twice (one per half)
    lat = np.concatenate([np.linspace(-np.pi / 2, 0, rings + 1), np.linspace(0, np.pi / 2, rings + 1)])
    top = np.repeat([False, True], rings + 1)
    lon = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    cl, sl = np.cos(lat)[:, None], np.sin(lat)[:, None]
    n_local = np.stack([cl * np.cos(lon), np.broadcast_to(sl, (len(lat), sides)), cl * np.sin(lon)], -1)
    normals = n_local @ np.stack([x, y, z])  # (L, S, 3) in world axes
    centre = np.where(top[:, None, None], b, a)
    pos = centre + radius * normals
    L = len(lat)
    i = np.arange(L - 1)[:, None] * sides
    s = np.arange(sides)[None, :]
    v00, v01 = i + s, i + (s + 1) % sides
    v10, v11 = v00 + sides, v01 + sides
    tris = np.concatenate([np.stack([v00, v10, v11], -1).reshape(-1, 3),
                           np.stack([v00, v11, v01], -1).reshape(-1, 3)])
    return pos.reshape(-1, 3), normals.reshape(-1, 3), tris


def body_mesh(offsets: np.ndarray, parents: tuple[int, ...], names: tuple[str, ...]
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The simple body in the rest pose (identity rotations, root at the origin): (V, 3) positions and
    (V, 3) normals in metres, (F, 3) triangles, (V,) joint index each vertex is bound to (weight 1)."""
    rest = forward_kinematics(offsets, None, offsets[0], parents)
    parts = []
    for c, p in enumerate(parents):
        if p < 0:
            continue
        parts.append((rest[p], rest[c], BONE_RADIUS.get(names[c], DEFAULT_RADIUS), p))
    for j, name in enumerate(names):
        if j in parents:
            continue  # not a leaf
        if name == "head":
            parts.append((rest[j], rest[j], HEAD_RADIUS, j))
        elif name.endswith("wrist") and parents[j] >= 0:
            d = offsets[j] / max(np.linalg.norm(offsets[j]), 1e-9)
            parts.append((rest[j], rest[j] + HAND_LENGTH * d, BONE_RADIUS.get(name, DEFAULT_RADIUS), j))
    pos, nrm, tri, joint = [], [], [], []
    count = 0
    for a, b, r, j in parts:
        p, n, t = _capsule(a, b, r)
        pos.append(p)
        nrm.append(n)
        tri.append(t + count)
        joint.append(np.full(len(p), j))
        count += len(p)
    return np.concatenate(pos), np.concatenate(nrm), np.concatenate(tri), np.concatenate(joint)


def _continuous_quats(q: np.ndarray) -> np.ndarray:
    """(T, ..., 4) quaternions with each key's sign flipped where needed to stay in the hemisphere of the
    previous one (linear keys then turn the short way)."""
    q = q.copy()
    for t in range(1, len(q)):
        flip = (q[t] * q[t - 1]).sum(-1) < 0
        q[t][flip] *= -1
    return q


def rigid_to_glb(motion: RigidMotion, fps: float | None = None, *, body: bool = True,
                 extras: dict | None = None) -> bytes:
    """The .glb file (bytes) of ``motion``: named joint nodes, a skin, a capsule body (``body``), one
    animation at ``fps`` (default the skeleton's) with a rotation per joint and the root's translation;
    ``extras``: more of how it was made, beside frame rate, frames, skeleton and units in the file's extras."""
    import pygltflib as g

    sk = get_skeleton(motion.skeleton)
    fps = float(fps or sk.fps)
    if not fps > 0:
        raise SMFError(f"fps must be positive, got {fps}")
    T, J = motion.rotations.shape[:2]
    if T < 1 or J != sk.num_joints:
        raise SMFError(f"expected rotations (T>=1, {sk.num_joints}, 3, 3), got {motion.rotations.shape}")
    parents, names = sk.parents, sk.joint_names
    quats = matrix_to_quat(motion.rotations.reshape(-1, 3, 3))[:, [1, 2, 3, 0]].reshape(T, J, 4)  # x, y, z, w
    quats = _continuous_quats(quats).astype(np.float32)
    quats /= np.linalg.norm(quats, axis=-1, keepdims=True)
    root = motion.root.astype(np.float32)
    times = (np.arange(T) / fps).astype(np.float32)

    blob = bytearray()
    views: list = []
    accessors: list = []

    def add(array: np.ndarray, component: int, kind: str, target: int | None = None, minmax: bool = False) -> int:
        data = np.ascontiguousarray(array).tobytes()
        blob.extend(b"\0" * (-len(blob) % 4))  # every view starts 4-byte aligned
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob.extend(data)
        count = len(array)
        acc = g.Accessor(bufferView=len(views) - 1, componentType=component, count=count, type=kind)
        if minmax:
            flat = array.reshape(count, -1)
            acc.min, acc.max = flat.min(0).tolist(), flat.max(0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    nodes = []
    children = [[c for c in range(J) if parents[c] == j] for j in range(J)]
    for j in range(J):
        node = g.Node(name=names[j], children=children[j] or None,
                      translation=(root[0] if parents[j] < 0 else motion.offsets[j]).astype(float).tolist(),
                      rotation=quats[0, j].astype(float).tolist())
        nodes.append(node)
    root_joint = parents.index(-1)

    gltf = g.GLTF2(asset=g.Asset(version="2.0", generator="stablemofusion"), scene=0)
    scene_nodes = [root_joint]
    if body:
        pos, nrm, tri, joint = body_mesh(np.asarray(motion.offsets, np.float64), parents, names)
        p_acc = add(pos.astype(np.float32), _FLOAT, "VEC3", _ARRAY_BUFFER, minmax=True)
        n_acc = add(nrm.astype(np.float32), _FLOAT, "VEC3", _ARRAY_BUFFER)
        joints4 = np.zeros((len(pos), 4), np.uint8)
        joints4[:, 0] = joint
        j_acc = add(joints4, _UBYTE, "VEC4", _ARRAY_BUFFER)
        weights = np.zeros((len(pos), 4), np.float32)
        weights[:, 0] = 1.0
        w_acc = add(weights, _FLOAT, "VEC4", _ARRAY_BUFFER)
        index_type = (np.uint16, _USHORT) if len(pos) < 65535 else (np.uint32, _UINT)
        i_acc = add(tri.reshape(-1).astype(index_type[0]), index_type[1], "SCALAR", _ELEMENT_ARRAY_BUFFER)
        offsets = np.asarray(motion.offsets, np.float64)
        rest = forward_kinematics(offsets, None, offsets[0], parents)
        ibm = np.tile(np.eye(4, dtype=np.float32), (J, 1, 1))
        ibm[:, 3, :3] = -rest  # column-major storage: the translation is the last column
        b_acc = add(ibm.reshape(J, 16), _FLOAT, "MAT4")
        gltf.materials = [g.Material(name="body", pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorFactor=list(BODY_COLOUR), metallicFactor=0.0, roughnessFactor=0.8))]
        gltf.meshes = [g.Mesh(name="body", primitives=[g.Primitive(
            attributes=g.Attributes(POSITION=p_acc, NORMAL=n_acc, JOINTS_0=j_acc, WEIGHTS_0=w_acc),
            indices=i_acc, material=0)])]
        gltf.skins = [g.Skin(name="skeleton", joints=list(range(J)), skeleton=root_joint, inverseBindMatrices=b_acc)]
        nodes.append(g.Node(name="body", mesh=0, skin=0))
        scene_nodes.append(len(nodes) - 1)

    t_acc = add(times, _FLOAT, "SCALAR", minmax=True)
    samplers, channels = [], []
    for j in range(J):
        samplers.append(g.AnimationSampler(input=t_acc, output=add(quats[:, j], _FLOAT, "VEC4"),
                                           interpolation="LINEAR"))
        channels.append(g.AnimationChannel(sampler=len(samplers) - 1,
                                           target=g.AnimationChannelTarget(node=j, path="rotation")))
    samplers.append(g.AnimationSampler(input=t_acc, output=add(root, _FLOAT, "VEC3"), interpolation="LINEAR"))
    channels.append(g.AnimationChannel(sampler=len(samplers) - 1,
                                       target=g.AnimationChannelTarget(node=root_joint, path="translation")))

    gltf.nodes = nodes
    gltf.scenes = [g.Scene(name="motion", nodes=scene_nodes)]
    gltf.animations = [g.Animation(name="motion", samplers=samplers, channels=channels)]
    gltf.accessors = accessors
    gltf.bufferViews = views
    blob.extend(b"\0" * (-len(blob) % 4))
    gltf.buffers = [g.Buffer(byteLength=len(blob))]
    gltf.extras = {"fps": fps, "frames": T, "skeleton": sk.name, "units": "metres, Y up", **(extras or {})}
    gltf.set_binary_blob(bytes(blob))
    return b"".join(gltf.save_to_bytes())


def save_glb(motion: RigidMotion, path, fps: float | None = None, *, body: bool = True) -> None:
    """Write :func:`rigid_to_glb` of ``motion`` to ``path``, atomically."""
    from ..core.io import write_bytes

    write_bytes(path, rigid_to_glb(motion, fps, body=body))
