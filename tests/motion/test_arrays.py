"""numpy and torch meet once, at the edges of the motion math: the functions are written in torch,
numpy float64 in gives numpy float64 out, torch in gives torch out (dtype kept, gradients flowing), and no
function of these modules looks at the array type itself."""

import ast
import inspect

import numpy as np
import pytest
import torch

from stablemofusion.footskate import underpressure
from stablemofusion.motion import arrays, features, rotation
from stablemofusion.motion.files import load_motion


@pytest.mark.parametrize("module", [rotation, features, underpressure])
def test_no_function_branches_on_the_array_type(module):
    """Only motion/arrays.py may ask whether something is a numpy array or a tensor."""
    found = []
    for node in ast.walk(ast.parse(inspect.getsource(module))):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance":
            kinds = ast.unparse(node.args[1])
            if any(word in kinds for word in ("Tensor", "ndarray", "generic", "np.", "numpy")):
                found.append(f"line {node.lineno}: {ast.unparse(node)}")
        if isinstance(node, ast.IfExp) and {"torch", "np"} <= {ast.unparse(node.body), ast.unparse(node.orelse)}:
            found.append(f"line {node.lineno}: {ast.unparse(node)}")  # lib = torch if ... else np
    assert not found, f"{module.__name__} branches on numpy versus torch: {found}"


def _motion():
    joints = load_motion("example:wave-both-hands").joints[:40].astype(np.float64)
    return joints, features.features_from_joints(joints)


def _cases():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(7, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q23 = np.broadcast_to(q[:5, None], (5, 23, 4)).copy()
    joints, feats = _motion()
    return {
        "qnormalize": (rotation.qnormalize, (rng.normal(size=(7, 4)),)),
        "qinv": (rotation.qinv, (q,)),
        "qmul": (rotation.qmul, (q, q[::-1].copy())),
        "qrot": (rotation.qrot, (q, rng.normal(size=(7, 3)))),
        "qbetween": (rotation.qbetween, (rng.normal(size=(7, 3)), rng.normal(size=(7, 3)))),
        "quat_to_matrix": (rotation.quat_to_matrix, (q,)),
        "quat_to_cont6d": (rotation.quat_to_cont6d, (q,)),
        "cont6d_to_matrix": (rotation.cont6d_to_matrix, (rng.normal(size=(7, 6)),)),
        "yaw_quat": (rotation.yaw_quat, (rng.normal(size=(7,)),)),
        "root_from_features": (features.root_from_features, (feats,)),
        "joints_from_features": (features.joints_from_features, (feats,)),
        "joints_from_rotations": (features.joints_from_rotations, (feats,)),
        "mirror_joints": (features.mirror_joints, (joints,)),
        "mirror_features": (features.mirror_features, (feats,)),
        "retarget_22_to_23": (underpressure.retarget_22_to_23, (joints,)),
        "forward_kinematics_23": (underpressure.forward_kinematics_23,
                                  (q23, underpressure.UP_REST[None].copy(), rng.normal(size=(5, 1, 3)))),
        "resample_time": (lambda x: underpressure.resample_time(x, 20.0, 100.0), (joints,)),
    }


CASES = _cases()


def _flat(out):
    return out if isinstance(out, tuple) else (out,)


@pytest.mark.parametrize("name", sorted(CASES))
def test_numpy_float64_in_numpy_float64_out(name):
    fn, args = CASES[name]
    for out in _flat(fn(*args)):
        assert type(out) is np.ndarray and out.dtype == np.float64, name


@pytest.mark.parametrize("name", sorted(CASES))
def test_torch_in_torch_out_with_gradients_and_the_same_numbers(name):
    fn, args = CASES[name]
    xs = [torch.tensor(a, requires_grad=True) for a in args]
    outs = _flat(fn(*xs))
    assert all(isinstance(o, torch.Tensor) and o.dtype == torch.float64 for o in outs), name
    sum(o.sum() for o in outs).backward()
    assert any(x.grad is not None and torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0 for x in xs), name
    for o, n in zip(outs, _flat(fn(*args))):
        np.testing.assert_allclose(o.detach().numpy(), n, rtol=0, atol=1e-12, err_msg=name)
    f32 = _flat(fn(*(torch.tensor(a, dtype=torch.float32) for a in args)))
    assert all(o.dtype == torch.float32 for o in f32), name


def test_float32_numpy_stays_float32_except_where_float64_math_is_promised():
    q = np.array([[1.0, 0.0, 0.0, 0.0]], dtype=np.float32)
    assert rotation.qinv(q).dtype == np.float32
    _, feats = _motion()
    assert features.joints_from_features(feats.astype(np.float32)).dtype == np.float64  # documented float64 math


def test_edge_takes_read_only_and_reversed_views():
    q = np.broadcast_to(np.array([1.0, 0.0, 0.0, 0.0]), (3, 4))  # read-only, zero strides
    v = np.arange(9.0).reshape(3, 3)[::-1]  # negative strides
    np.testing.assert_allclose(rotation.qrot(q, v), v)
    assert isinstance(arrays.to_torch(v), torch.Tensor)
