"""The Blender add-on (`smf addon`: stablemofusion/assets/blender_addon with the package's retargeting math and
joint maps in one zip); headless in Debian's Blender it installs from a zip, asks a (stand-in) `smf serve`
for a motion and the armature's bones follow it: a Mixamo-style armature, and our own skeleton it creates."""

from __future__ import annotations

import json
import shutil
import subprocess
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest

from stablemofusion.cli.main import main
from stablemofusion.motion.bvh import read_bvh
from stablemofusion.motion.files import load_motion, rigid_pose
from stablemofusion.motion.retarget import JointMap
from stablemofusion.motion.skeleton import HUMANML3D

REPO = Path(__file__).resolve().parents[1]
ADDON = REPO / "stablemofusion" / "assets" / "blender_addon"
PACKAGE = REPO / "stablemofusion"
MIXAMO_RIG = REPO / "tests" / "data" / "mixamo_tpose.bvh"
LIMBS = ((16, 18), (18, 20), (17, 19), (19, 21), (1, 4), (4, 7), (2, 5), (5, 8))
FRAMES = (1, 30, 60, 118)  # Blender frames (1-based): motion frames 0, 29, 59, 117


def test_addon_zip_holds_the_package_files(tmp_path):
    import zipfile

    out = tmp_path / "addon.zip"
    assert main(["addon", "--out", str(out)]) == 0
    with zipfile.ZipFile(out) as z:
        names = set(z.namelist())
        assert z.read("stablemofusion_addon/rig.py") == (PACKAGE / "motion" / "rig.py").read_bytes()
        maps = sorted(p.name for p in (PACKAGE / "assets" / "joint_maps").glob("*.json"))
        assert {f"stablemofusion_addon/joint_maps/{m}" for m in maps} <= names
        assert {"stablemofusion_addon/__init__.py", "stablemofusion_addon/motion.py"} <= names
    assert main(["addon", "--out", str(tmp_path / "addon.tar")]) == 2
    text = (ADDON / "motion.py").read_text()
    for name in HUMANML3D.joint_names:
        assert f'"{name}"' in text
    assert f"PARENTS = {tuple(HUMANML3D.parents)}" in text
    rest = text[text.index("REST_DIRECTIONS = ("):]
    rest = eval(rest[len("REST_DIRECTIONS = "):rest.index("\n)") + 2])  # noqa: S307 - our own file
    assert np.array_equal(np.array(rest, float), HUMANML3D.offsets_array)


SCRIPT = r"""
import bpy, json, sys
zip_path, rig_json, url, out = sys.argv[sys.argv.index('--') + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path)
bpy.ops.preferences.addon_enable(module='stablemofusion_addon')
scene = bpy.context.scene
scene.smf.prompt, scene.smf.seconds, scene.smf.seed = 'a person waves with both hands', 5.9, 7
scene.smf.backend, scene.smf.server = 'SERVER', url
result = {}

def heads(arm, frames):
    got = []
    for f in frames:
        scene.frame_set(f)
        got.append({b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones})
    return got

# 1. a Mixamo-style armature (bone heads from the BVH's rest pose; Debian's BVH importer fails on Python 3.11),
# selected
rig = json.load(open(rig_json))
data = bpy.data.armatures.new('mixamo')
arm = bpy.data.objects.new('mixamo', data)
scene.collection.objects.link(arm)
bpy.context.view_layer.objects.active = arm
bpy.ops.object.mode_set(mode='EDIT')
for name, parent, head, tail in zip(rig['names'], rig['parents'], rig['heads'], rig['tails']):
    eb = data.edit_bones.new(name)
    eb.head, eb.tail = head, tail
    if parent >= 0:
        eb.parent = data.edit_bones[rig['names'][parent]]
bpy.ops.object.mode_set(mode='OBJECT')
arm.select_set(True)
result['mixamo_status'] = list(bpy.ops.smf.generate_motion())
result['mixamo'] = heads(arm, %(frames)s)
result['frame_range'] = [scene.frame_start, scene.frame_end, scene.render.fps]
# 2. nothing selected: the add-on creates our skeleton
arm.select_set(False)
bpy.context.view_layer.objects.active = None
result['ours_status'] = list(bpy.ops.smf.generate_motion())
ours = bpy.data.objects['stablemofusion']
result['ours'] = heads(ours, %(frames)s)
# 3. a render (F12) shows the character: the body parented to our armature's bones
result['body'] = sorted(o.parent_bone for o in bpy.data.objects if o.parent == ours)
cam_data = bpy.data.cameras.new('cam')
cam = bpy.data.objects.new('cam', cam_data)
scene.collection.objects.link(cam)
scene.camera = cam
scene.frame_set(40)
cam.location = (ours.matrix_world @ ours.pose.bones['pelvis'].head) + __import__('mathutils').Vector((0, -4.5, 0.2))
cam.rotation_euler = (1.5708, 0, 0)
scene.render.engine = 'BLENDER_WORKBENCH'
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 96, 96, 100
def covered(path):
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path)
    px = list(img.pixels)
    first = px[:4]
    return sum(1 for i in range(0, len(px), 4) if abs(px[i] - first[0]) + abs(px[i + 1] - first[1]) > 0.05)
result['covered'] = covered(out + '.with.png')
for o in bpy.data.objects:
    if o.parent == ours:
        o.hide_render = True
result['covered_without_body'] = covered(out + '.without.png')
json.dump(result, open(out, 'w'))
""" % {"frames": FRAMES}


class _Server(BaseHTTPRequestHandler):
    joints: np.ndarray
    requests: list = []

    def do_POST(self):  # noqa: N802 - http.server's name
        body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
        type(self).requests.append((self.path, body))
        data = json.dumps({"prompt": body["prompt"], "fps": 20.0, "frames": len(self.joints), "seed": body["seed"],
                           "joints": np.round(self.joints, 5).tolist()}).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    def log_message(self, *args):
        pass


def _armature(bvh) -> dict:
    """Bones of a BVH's rest pose for Blender (Z up, metres): names, parents, heads, tails (towards the first
    child, else 5 cm on along the bone)."""
    pos = np.zeros((bvh.num_joints, 3))
    for j, p in enumerate(bvh.parents):
        pos[j] = bvh.offsets[j] + (pos[p] if p >= 0 else 0)
    tails = []
    for j in range(bvh.num_joints):
        kids = np.flatnonzero(bvh.parents == j)
        step = pos[kids[0]] - pos[j] if len(kids) else bvh.offsets[j]
        if np.linalg.norm(step) < 1e-3:
            step = np.array([0.0, 0.05, 0.0])
        tails.append(pos[j] + (step if len(kids) else 0.05 * step / np.linalg.norm(step)))
    z_up = lambda v: np.stack([v[:, 0], -v[:, 2], v[:, 1]], -1).tolist()  # noqa: E731
    return {"names": bvh.names, "parents": bvh.parents.tolist(), "heads": z_up(pos), "tails": z_up(np.array(tails))}


def _to_ours(heads: dict, names: list[str], scale: float = 1.0) -> np.ndarray:
    """Blender world heads (Z up) of the named bones -> (22, 3) Y up."""
    v = np.array([heads[n] for n in names])
    return np.stack([v[:, 0], v[:, 2], -v[:, 1]], -1) / scale


def _limb_cosine(a: np.ndarray, b: np.ndarray) -> float:
    def unit(x, i, j):
        v = x[..., j, :] - x[..., i, :]
        return v / np.linalg.norm(v, axis=-1, keepdims=True)
    return float(np.mean([(unit(a, i, j) * unit(b, i, j)).sum(-1).mean() for i, j in LIMBS]))


def test_addon_headless_in_blender(tmp_path):
    if shutil.which("blender") is None:
        pytest.skip("blender is not installed (Debian: apt-get install blender python3-numpy; .ci/run does)")
    joints = rigid_pose(load_motion("example:wave-both-hands").joints).joints()
    _Server.joints, _Server.requests = joints, []
    server = ThreadingHTTPServer(("127.0.0.1", 0), _Server)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        zip_path = tmp_path / "stablemofusion_addon.zip"
        assert main(["addon", "--out", str(zip_path)]) == 0
        script, out, rig_json = tmp_path / "run.py", tmp_path / "out.json", tmp_path / "rig.json"
        script.write_text(SCRIPT)
        rig_json.write_text(json.dumps(_armature(read_bvh(MIXAMO_RIG))))
        env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "BLENDER_USER_SCRIPTS": str(tmp_path / "scripts")}
        run = subprocess.run(["blender", "-b", "--factory-startup", "--python", str(script), "--", str(zip_path),
                              str(rig_json), f"http://127.0.0.1:{server.server_address[1]}", str(out)],
                             capture_output=True, text=True, timeout=600, env=env)
    finally:
        server.shutdown()
    assert out.is_file(), run.stdout[-3000:] + run.stderr[-3000:]
    got = json.loads(out.read_text())
    assert got["mixamo_status"] == ["FINISHED"] and got["ours_status"] == ["FINISHED"], run.stdout[-3000:]
    assert [p for p, _ in _Server.requests] == ["/v1/generate"] * 2
    assert _Server.requests[0][1] == {"prompt": "a person waves with both hands", "seconds": pytest.approx(5.9),
                                      "seed": 7}
    assert got["frame_range"] == [1, len(joints), 20]
    idx = [f - 1 for f in FRAMES]
    # the Mixamo-style armature: its mapped bones point where ours do
    mixamo_names = [s[0] for s in JointMap.named("mixamo").sources]
    mixamo = np.stack([_to_ours(h, mixamo_names) for h in got["mixamo"]])
    cos = _limb_cosine(joints[idx], mixamo)
    assert cos >= 0.98, cos
    # the skeleton it created: our joint names; limbs and the pelvis path follow the motion
    ours = np.stack([_to_ours(h, list(HUMANML3D.joint_names)) for h in got["ours"]])
    assert np.abs(ours - joints[idx]).max() < 1e-3  # the created skeleton takes the (rigid) motion's poses exactly
    # a render shows the character: its body covers part of the frame, which without it stays empty
    assert "head" in got["body"] and len(got["body"]) >= 18
    assert got["covered"] > 300 and got["covered_without_body"] == 0, (got["covered"], got["covered_without_body"])
    print(f"Blender add-on: limb cosine {cos:.5f} on the Mixamo-style armature")


LOCAL_SCRIPT = r"""
import bpy, json, sys
zip_path, packages, out = sys.argv[sys.argv.index('--') + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path)
bpy.ops.preferences.addon_enable(module='stablemofusion_addon')
scene = bpy.context.scene
scene.smf.prompt, scene.smf.seconds, scene.smf.seed, scene.smf.backend = 'a person waves both hands happily', 4, 7, 'LOCAL'
try:  # the packages folder not set yet: one clear error
    bpy.ops.smf.generate_motion()
    result = {'missing': 'no error'}
except RuntimeError as e:
    result = {'missing': str(e)}
scene.smf.backend, scene.smf.server = 'AUTO', 'http://127.0.0.1:9'  # neither a server nor the packages: both named
try:
    bpy.ops.smf.generate_motion()
    result['neither'] = 'no error'
except RuntimeError as e:
    result['neither'] = str(e)
scene.smf.backend = 'LOCAL'
bpy.context.preferences.addons['stablemofusion_addon'].preferences.packages = packages
result['status'] = list(bpy.ops.smf.generate_motion())
addon = sys.modules['stablemofusion_addon']
result['joints'] = addon.motion.LAST_JOINTS.tolist()
ours = bpy.data.objects['stablemofusion']
got = []
for f in range(1, len(result['joints']) + 1):
    scene.frame_set(f)
    got.append({b.name: list(ours.matrix_world @ b.head) for b in ours.pose.bones})
result['ours'] = got
scene.smf.prompt, scene.smf.seconds = 'a tired man walks in a circle then waves', 6  # a prompt of two parts
ours.select_set(True)  # regenerated onto the same armature
bpy.context.view_layer.objects.active = ours
bpy.ops.smf.generate_motion()
result['sequence'] = addon.motion.LAST_JOINTS.tolist()
result['actions'] = [a.name for a in bpy.data.actions]
scene.smf.prompt, scene.smf.seconds = 'un homme marche lentement vers la porte', 3  # warned: shown in the panel
result['french'] = list(bpy.ops.smf.generate_motion())
result['warnings'] = list(addon.motion.LAST_WARNINGS)
json.dump(result, open(out, 'w'))
"""


def test_addon_generates_in_blender_without_a_server(tmp_path, blender_shares_python):
    """Backend 'In Blender': the portable runtime in Blender's own Python (its packages from this test's
    site-packages, Blender's numpy kept), the CLI's joints; without the runtime, one clear error."""
    import site

    zip_path, script, out = tmp_path / "stablemofusion_addon.zip", tmp_path / "run.py", tmp_path / "out.json"
    assert main(["addon", "--out", str(zip_path)]) == 0
    script.write_text(LOCAL_SCRIPT)
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "BLENDER_USER_SCRIPTS": str(tmp_path / "scripts")}
    run = subprocess.run(["blender", "-b", "--factory-startup", "--python", str(script), "--", str(zip_path),
                          site.getsitepackages()[0], str(out)], capture_output=True, text=True, timeout=600, env=env)
    assert out.is_file(), run.stdout[-3000:] + run.stderr[-3000:]
    got = json.loads(out.read_text())
    assert "not importable in Blender's Python" in got["missing"] and "Traceback" not in got["missing"]
    assert "smf serve" in got["neither"] and "packages folder" in got["neither"], got["neither"]
    assert got["status"] == ["FINISHED"], run.stdout[-3000:]
    cli = tmp_path / "cli"
    assert main(["generate", "a person waves both hands happily", "--seconds", "4", "--seed", "7", "--engine", "onnx",
                 "--format", "npy", "--out", str(cli)]) == 0
    want = np.load(next(cli.glob("*_joints.npy")))
    assert np.abs(np.asarray(got["joints"]) - want).max() < 1e-3
    ours = np.stack([_to_ours(h, list(HUMANML3D.joint_names)) for h in got["ours"]])  # every frame's bone heads
    assert np.abs(ours - want).max() < 1e-3  # the skeleton it created takes every pose of the motion exactly
    # a prompt of two parts in Blender: made part after part, as the CLI makes it (the walk, then the wave)
    assert main(["generate", "a tired man walks in a circle then waves", "--seconds", "6", "--seed", "7", "--engine",
                 "onnx", "--format", "npy", "--out", str(tmp_path / "seq")]) == 0
    want = np.load(next((tmp_path / "seq").glob("*_joints.npy")))
    assert np.abs(np.asarray(got["sequence"]) - want).max() < 1e-3
    assert got["actions"] == ["a tired man walks in a circle then waves"]  # one action, reused: no orphan left
    assert got["french"] == ["FINISHED"] and len(got["warnings"]) >= 1  # and out of domain
    assert "does not look like English (French words)" in got["warnings"][0]
