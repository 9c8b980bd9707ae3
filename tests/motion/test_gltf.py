"""glTF 2.0 export: structure, the animation played through the node tree equals the joints, the Khronos
validator finds no errors, Blender imports it."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from stablemofusion.motion.files import load_motion, rigid_pose
from stablemofusion.motion.gltf import rigid_to_glb, save_glb
from stablemofusion.motion.skeleton import HUMANML3D

from gltf_tools import VALIDATE_JS, gltf_validator_dir, play_node_tree, read_glb


@pytest.fixture(scope="module")
def wave(tmp_path_factory):
    """The packaged example as a rigid body, its .glb and its joints .npy (float32, as files hold them)."""
    out = tmp_path_factory.mktemp("glb")
    motion = rigid_pose(load_motion("example:wave-both-hands").joints)
    save_glb(motion, out / "wave.glb", fps=20.0)
    np.save(out / "wave_joints.npy", motion.joints().astype(np.float32))
    return motion, out / "wave.glb", out / "wave_joints.npy"


def test_structure_named_joint_nodes_skin_one_animation(wave):
    motion, path, _ = wave
    doc, blob = read_glb(path)
    names = [n["name"] for n in doc["nodes"]]
    assert names[:22] == list(HUMANML3D.joint_names)
    assert doc["skins"][0]["joints"] == list(range(22)) and doc["skins"][0]["skeleton"] == 0
    body = doc["nodes"][22]
    assert body["skin"] == 0 and body["mesh"] == 0 and "children" not in body
    assert doc["scenes"][0]["nodes"] == [0, 22]
    assert len(doc["animations"]) == 1
    channels = doc["animations"][0]["channels"]
    assert sorted((c["target"]["node"], c["target"]["path"]) for c in channels) == sorted(
        [(j, "rotation") for j in range(22)] + [(0, "translation")])
    assert doc["extras"]["fps"] == 20.0 and doc["extras"]["frames"] == len(motion)
    # the body: a few thousand vertices, each bound to one joint with weight 1
    prim = doc["meshes"][0]["primitives"][0]
    assert 1000 < doc["accessors"][prim["attributes"]["POSITION"]]["count"] < 20000


def test_animation_through_node_tree_equals_joints_npy(wave):
    motion, path, joints_file = wave
    names, times, pos = play_node_tree(path)
    joints = np.load(joints_file)
    assert np.allclose(times, np.arange(len(joints)) / 20.0, atol=1e-6)
    err = np.linalg.norm(pos[:, :22] - joints, axis=-1)
    assert err.max() < 1e-3, f"node tree vs joints .npy: max {err.max() * 1000:.3f} mm"
    print(f"glTF node tree vs joints .npy: max error {err.max() * 1000:.4f} mm")


def test_kit_motion_and_no_body():
    rng = np.random.default_rng(0)
    from stablemofusion.motion.rotation import quat_to_matrix
    from stablemofusion.motion.rigid import RigidMotion
    from stablemofusion.motion.skeleton import KIT

    q = rng.normal(size=(5, 21, 4))
    motion = RigidMotion(KIT.offsets_array * 0.2, quat_to_matrix(q / np.linalg.norm(q, axis=-1, keepdims=True)),
                         rng.normal(size=(5, 3)), "kit")
    data = rigid_to_glb(motion, body=False)
    assert data[:4] == b"glTF"
    doc = json.loads(data[20:20 + int.from_bytes(data[12:16], "little")])
    assert "meshes" not in doc and [n["name"] for n in doc["nodes"]] == list(KIT.joint_names)


def test_khronos_validator_finds_no_errors(wave, tmp_path):
    tools = gltf_validator_dir()
    if tools is None:
        pytest.skip("node or the npm package gltf-validator is absent (.ci/run installs it into "
                    "~/.cache/stablemofusion-tools; or set SMF_TOOLS to a folder holding node_modules/gltf-validator)")
    script = tmp_path / "validate.cjs"
    script.write_text(VALIDATE_JS)
    out = subprocess.run(["node", str(script), str(wave[1]), str(tools / "node_modules" / "gltf-validator")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    issues = json.loads(out.stdout)
    print(f"gltf-validator: {issues['numErrors']} errors, {issues['numWarnings']} warnings, "
          f"{issues['numInfos']} infos, {issues['numHints']} hints")
    assert issues["numErrors"] == 0, issues["messages"]
    assert issues["numWarnings"] == 0, issues["messages"]


BLENDER_IMPORT = """
import bpy, json, sys
path, out = sys.argv[sys.argv.index('--') + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.context.scene.render.fps = 20
bpy.ops.import_scene.gltf(filepath=path)
arm = next(o for o in bpy.data.objects if o.type == 'ARMATURE')
meshes = [o.name for o in bpy.data.objects if o.type == 'MESH']
heads = []
for f in (0, 10, 40):
    bpy.context.scene.frame_set(f)
    heads.append({b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones})
json.dump({"bones": [b.name for b in arm.data.bones], "meshes": meshes,
           "actions": [a.name for a in bpy.data.actions], "heads": heads}, open(out, 'w'))
"""


def test_blender_imports_glb(wave, tmp_path):
    if shutil.which("blender") is None:
        pytest.skip("blender is not installed (Debian: apt-get install blender python3-numpy)")
    motion, path, joints_file = wave
    script, out = tmp_path / "imp.py", tmp_path / "imp.json"
    script.write_text(BLENDER_IMPORT)
    run = subprocess.run(["blender", "-b", "--factory-startup", "--python", str(script), "--", str(path), str(out)],
                         capture_output=True, text=True, timeout=300)
    assert out.is_file(), run.stdout[-2000:] + run.stderr[-2000:]
    got = json.loads(out.read_text())
    assert set(HUMANML3D.joint_names) <= set(got["bones"]) and got["meshes"] and got["actions"]
    joints = np.load(joints_file).astype(np.float64)
    for f, heads in zip((0, 10, 40), got["heads"]):
        blender = np.array([heads[n] for n in HUMANML3D.joint_names])
        ours = joints[f][:, [0, 2, 1]] * np.array([1, -1, 1])  # Y up -> Blender's Z up: (x, -z, y)
        assert np.abs(blender - ours).max() < 2e-3, f"frame {f}: {np.abs(blender - ours).max()}"
