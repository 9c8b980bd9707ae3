"""One forward kinematics (motion/kinematics.py): the BVH reader and the rigid body agree through it, numpy and
torch give the same joints, and no second loop composing transforms down a tree's parents appears."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
import torch

import stablemofusion
from stablemofusion.core.errors import SMFError
from stablemofusion.motion import bvh as bvh_module
from stablemofusion.motion.bvh import forward_kinematics as bvh_fk
from stablemofusion.motion.bvh import read_bvh
from stablemofusion.motion.files import load_motion, save_rigid_bvh
from stablemofusion.motion.kinematics import forward_kinematics
from stablemofusion.motion.rigid import RigidMotion, fit_rigid, global_rotations
from stablemofusion.motion.rigid import forward_kinematics as rigid_fk
from stablemofusion.motion.skeleton import HUMANML3D

PACKAGE = Path(stablemofusion.__file__).resolve().parent
PARENTS = HUMANML3D.parents


@pytest.fixture(scope="module")
def body() -> RigidMotion:
    return fit_rigid(load_motion("example:wave-both-hands").joints.astype(np.float64))


def _reference_fk(offsets, rotations, root, parents):
    """The convention written out joint by joint (test-only reference)."""
    glob, pos = np.empty_like(rotations), np.empty(rotations.shape[:-1])
    for j, p in enumerate(parents):
        if p < 0:
            glob[:, j], pos[:, j] = rotations[:, j], root
        else:
            glob[:, j] = glob[:, p] @ rotations[:, j]
            pos[:, j] = pos[:, p] + glob[:, p] @ offsets[j]
    return pos


def test_bvh_and_rigid_forward_kinematics_agree_on_one_skeleton(body, tmp_path):
    """One skeleton and one set of rotations through the BVH reader (Euler channels -> local rotations ->
    positions) and through the rigid body: the same joints to 1e-12 m, and those of the written-out definition."""
    from scipy.spatial.transform import Rotation

    J = HUMANML3D.num_joints
    channels = [["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"]] + \
        [["Zrotation", "Xrotation", "Yrotation"]] * (J - 1)
    angles = Rotation.from_matrix(body.rotations.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True).reshape(-1, J, 3)
    b = bvh_module.BVH(names=list(HUMANML3D.joint_names), parents=np.array(PARENTS), offsets=body.offsets,
                       channels=channels, end_sites={}, frame_time=0.05,
                       motion=np.concatenate([body.root, angles.reshape(len(body), -1)], axis=1))
    rotations = b.rotations()  # the reader's local rotations of the channels
    assert np.abs(rotations - body.rotations).max() < 1e-9  # the body's, to the Euler round trip
    from_bvh = bvh_fk(b)
    same_pose = RigidMotion(body.offsets, rotations, body.root)
    assert np.abs(same_pose.joints() - from_bvh).max() < 1e-12
    assert np.abs(rigid_fk(torch.from_numpy(body.offsets), torch.from_numpy(rotations), torch.from_numpy(body.root),
                           PARENTS).numpy() - from_bvh).max() < 1e-12
    assert np.abs(_reference_fk(body.offsets, rotations, body.root, PARENTS) - from_bvh).max() < 1e-12
    # through a written file (6 decimals, depth-first order): the reader's joints are the rigid body's, to the
    # file's rounding
    path = tmp_path / "body.bvh"
    save_rigid_bvh(body, path)
    back = read_bvh(path, unit="m")  # joints in file (depth-first) order
    order = [back.names.index(n) for n in HUMANML3D.joint_names]
    assert np.abs(bvh_fk(back)[:, order] - body.joints()).max() < 1e-5


def test_numpy_and_torch_give_the_same_joints_and_torch_is_differentiable(body):
    off, rot, root = body.offsets, body.rotations, body.root
    x_np = forward_kinematics(off, rot, root, PARENTS)
    assert isinstance(x_np, np.ndarray) and x_np.dtype == np.float64
    t_rot = torch.from_numpy(rot).requires_grad_(True)
    x_t = forward_kinematics(torch.from_numpy(off), t_rot, torch.from_numpy(root), PARENTS)
    assert isinstance(x_t, torch.Tensor) and np.abs(x_t.detach().numpy() - x_np).max() < 1e-12  # numpy and torch round alike
    x_t.sum().backward()
    assert t_rot.grad is not None and torch.isfinite(t_rot.grad).all()
    # batch dims broadcast: per-motion offsets (M, 1, J, 3) against (M, T, J, 3, 3)
    both = forward_kinematics(np.stack([off, off])[:, None], np.stack([rot, rot]), np.stack([root, root]), PARENTS)
    assert both.shape == (2,) + x_np.shape and np.abs(both - x_np).max() == 0.0


def test_global_rotations_and_the_rest_pose(body):
    glob = global_rotations(body)
    for j, p in enumerate(PARENTS):  # the definition, G_j = G_p @ R_j, written out for the check
        want = body.rotations[:, j] if p < 0 else glob[:, p] @ body.rotations[:, j]
        assert np.abs(glob[:, j] - want).max() < 1e-12
    rest = forward_kinematics(body.offsets, None, np.zeros(3), PARENTS)
    identity = np.broadcast_to(np.eye(3), (HUMANML3D.num_joints, 3, 3))
    assert np.abs(rest - forward_kinematics(body.offsets, identity, np.zeros(3), PARENTS)).max() < 1e-15


@pytest.mark.parametrize("parents", [(), (0, -1), (-1, 2, 0), (-1, -1)])
def test_bad_trees_are_refused(parents):
    with pytest.raises(SMFError):
        forward_kinematics(np.zeros((len(parents), 3)), None, np.zeros(3), parents)


# --- the source check -------------------------------------------------------------------------------------
# A forward kinematics is a recurrence down a tree: a value read from an array at a joint's parent, combined
# with something (+ a bone, @ a rotation), written to (or appended to) the same array. Only kinematics.py may
# hold one. The exceptions, each with its reason:
ALLOWED = {
    "motion/kinematics.py": "the one forward kinematics",
    # The Blender add-on ships motion/rig.py verbatim (tests/test_blender_addon.py): numpy only, no import from
    # the package, so it cannot call the torch function; it keeps its own rest positions and positions.
    "motion/rig.py": "the Blender add-on's numpy-only copy",
    # HumanML3D's recover_from_rot: every chain restarts from the root rotation, and a rotation is indexed by
    # the bone's child, so a joint with several children has several frames: not a tree FK over parents.
    "motion/features.py:joints_from_rotations": "HumanML3D's chain convention",
    # UnderPressure's 23-joint FK from *global* quaternions (footskate/, outside motion/).
    "footskate/underpressure.py:forward_kinematics_23": "UnderPressure's global-rotation FK",
    # Runs inside Blender, which has numpy but no torch: the add-on's rest armature.
    "assets/blender_addon/motion.py:create_our_armature": "Blender-side code without torch",
}
PARENT_NAMES = {"p", "ps", "par", "parent", "parents", "g_par"}


def _mentions_parent(node: ast.AST) -> bool:
    """Whether a subscript index reads a parent: a name like ``p``/``parent``, or ``parents[...]``."""
    for n in ast.walk(node):
        if isinstance(n, ast.Name) and n.id in PARENT_NAMES:
            return True
        if isinstance(n, ast.Attribute) and n.attr == "parents":
            return True
    return False


def _base(node: ast.AST) -> str | None:
    while isinstance(node, ast.Subscript):
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def _reads_own_parent(value: ast.AST, target: str) -> bool:
    """Whether ``value`` combines (+, @) ``target[... parent ...]`` with something that is not a constant."""
    for n in ast.walk(value):
        if isinstance(n, ast.BinOp) and isinstance(n.op, (ast.Add, ast.MatMult)):
            for side, other in ((n.left, n.right), (n.right, n.left)):
                if isinstance(side, ast.IfExp):  # rest[j] = offsets[j] + (rest[p] if p >= 0 else 0.0)
                    side = side.body
                if isinstance(side, ast.Subscript) and _base(side) == target and _mentions_parent(side.slice) \
                        and not isinstance(other, ast.Constant):
                    return True
    return False


def fk_recurrences(source: str) -> list[tuple[str, int]]:
    """(function name, line) of every tree recurrence (see above) in ``source``."""
    found = []
    for fn in ast.walk(ast.parse(source)):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for n in ast.walk(fn):
            if isinstance(n, ast.Assign):
                targets = [_base(t) for t in n.targets if isinstance(t, ast.Subscript)]
                if any(t and _reads_own_parent(n.value, t) for t in targets):
                    found.append((fn.name, n.lineno))
            elif isinstance(n, ast.AugAssign) and isinstance(n.op, (ast.Add, ast.MatMult)):
                t = _base(n.target)
                if t and isinstance(n.target, ast.Subscript) and not _mentions_parent(n.target.slice) and \
                        isinstance(n.value, ast.Subscript) and _base(n.value) == t and _mentions_parent(n.value.slice):
                    found.append((fn.name, n.lineno))
            elif isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr == "append":
                t = _base(n.func.value)
                if t and any(_reads_own_parent(a, t) for a in n.args):
                    found.append((fn.name, n.lineno))
    return found


def test_the_check_finds_the_forward_kinematics_it_replaced():
    """The loops removed (BVH's, the rest pose's, the L-BFGS fit's, the global rotations') are found."""
    old_bvh = ("def fk(bvh):\n    for j, p in enumerate(bvh.parents):\n"
               "        glob[:, j] = glob[:, p] @ rot[:, j]\n"
               "        pos[:, j] = pos[:, p] + np.einsum('fik,fk->fi', glob[:, p], trans[:, j])\n")
    rest = "def rest(o, parents):\n    pos = o.copy()\n    for j, p in enumerate(parents):\n        pos[j] += pos[p]\n"
    lbfgs = ("def positions():\n    for j in range(1, J):\n        p = parents[j]\n"
             "        pos.append(pos[p] + u[:, j])\n")
    levels = "def fk():\n    for d in ds:\n        ps = t.parents[js]\n        pos[:, js] = pos[:, ps] + off[:, js]\n"
    gltf = ("def rest(o, parents):\n    for j, p in enumerate(parents):\n"
            "        r[j] = o[j] + (r[p] if p >= 0 else 0.0)\n")
    assert [len(fk_recurrences(s)) for s in (old_bvh, rest, lbfgs, levels, gltf)] == [2, 1, 1, 1, 1]
    bookkeeping = ("def tree(parents):\n    for j in range(1, J):\n        depth[j] = depth[parents[j]] + 1\n"
                   "    for c in range(J - 1, 0, -1):\n        subtree[parents[c]] += subtree[c]\n")
    assert fk_recurrences(bookkeeping) == []


def test_only_the_kinematics_module_composes_transforms_down_a_tree():
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel in ALLOWED:
            continue
        found += [f"{rel}:{name} (line {line})" for name, line in fk_recurrences(path.read_text(encoding="utf-8"))
                  if f"{rel}:{name}" not in ALLOWED]
    assert not found, ("a second forward kinematics: call stablemofusion.motion.kinematics.forward_kinematics "
                       f"instead of composing transforms down the parents here: {found}")
