"""Tests of the BVH reader, forward kinematics and writer."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stablemofusion.core.errors import MotionFormatError, SMFError
from stablemofusion.motion.bvh import BVH, forward_kinematics, read_bvh, write_bvh

BANDAI_CHANNELS = ["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"]
BANDAI_JOINTS = ["joint_Root", "Hips", "Spine", "Chest", "Neck", "Head", "Shoulder_L", "UpperArm_L",
                 "LowerArm_L", "Hand_L", "Shoulder_R", "UpperArm_R", "LowerArm_R", "Hand_R", "UpperLeg_L",
                 "LowerLeg_L", "Foot_L", "Toes_L", "UpperLeg_R", "LowerLeg_R", "Foot_R", "Toes_R"]

# Unusual layout, centimetres: a 3-channel (position only) root; "XYZ" rotations; a child with a position
# channel interleaved with a rotation; a joint without CHANNELS; interleaved "Zrotation Xposition
# Yrotation"; a joint name with a space; tabs, blank lines, trailing spaces (CRLF is added when written).
SYNTH = """HIERARCHY
ROOT root
{
\tOFFSET 0 0 0
\tCHANNELS 3 Xposition Yposition Zposition
\tJOINT a
\t{
\t\tOFFSET  0 10 0
\t\tCHANNELS 3 Xrotation Yrotation Zrotation
\t\tJOINT b
\t\t{
\t\t\tOFFSET 10 0 0
\t\t\tCHANNELS 2 Yposition Zrotation
\t\t\tJOINT c
\t\t\t{
\t\t\t\tOFFSET 0 0 10
\t\t\t\tEnd Site
\t\t\t\t{
\t\t\t\t\tOFFSET 1 2 3
\t\t\t\t}
\t\t\t}
\t\t}
\t}
\tJOINT d
\t{
\t\tOFFSET -5 0 0
\t\tCHANNELS 3 Zrotation Xposition Yrotation
\t\tJOINT e tip
\t\t{
\t\t\tOFFSET 10 0 0
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0 0 0
\t\t\t}
\t\t}
\t}
}

MOTION
Frames:   2
Frame Time:\t0.05
0 0 0  0 0 0  0 0  0 0 0 \t
100 0 0  90 90 0  5 90  90 -20 90
"""
SYNTH_LINES = SYNTH.splitlines()
# Hand-computed world positions (cm). Frame 0: d's Xposition 0 replaces its -5 offset. Frame 1:
# G_a = Rx(90) Ry(90) = [[0,0,1],[1,0,0],[0,1,0]]; b = a + G_a (10, 5, 0); G_b = G_a Rz(90) ->
# c = b + G_b (0, 0, 10) = b + (10, 0, 0); d = root + (-20, 0, 0); e = d + Rz(90) Ry(90) (10, 0, 0).
SYNTH_EXPECTED = np.array([
    [[0, 0, 0], [0, 10, 0], [10, 10, 0], [10, 10, 10], [0, 0, 0], [10, 0, 0]],
    [[100, 0, 0], [100, 10, 0], [100, 20, 5], [110, 20, 5], [80, 0, 0], [80, 0, -10]],
], dtype=float) / 100


def _write(path: Path, text: str, crlf: bool = True) -> Path:
    path.write_bytes(text.replace("\n", "\r\n" if crlf else "\n").encode())
    return path


@pytest.fixture
def synth(tmp_path: Path) -> Path:
    return _write(tmp_path / "synth.bvh", SYNTH)


# ---------------------------------------------------------------- synthetic file


def test_synthetic_structure_and_units(synth: Path) -> None:
    bvh = read_bvh(synth)
    assert bvh.unit == "cm"  # rest-pose height 12 (c's end site): centimetres
    assert bvh.names == ["root", "a", "b", "c", "d", "e tip"]
    assert bvh.parents.tolist() == [-1, 0, 1, 2, 0, 4]
    assert bvh.channels[2] == ["Yposition", "Zrotation"] and bvh.channels[3] == [] and bvh.channels[5] == []
    np.testing.assert_allclose(bvh.offsets[4], [-0.05, 0, 0])
    assert sorted(bvh.end_sites) == [3, 5]
    np.testing.assert_allclose(bvh.end_sites[3], [0.01, 0.02, 0.03])
    assert bvh.num_frames == 2 and bvh.motion.shape == (2, 11)
    assert bvh.frame_time == 0.05 and bvh.fps == pytest.approx(20)
    np.testing.assert_allclose(bvh.motion[1, :3], [1, 0, 0])  # positions in metres
    np.testing.assert_allclose(bvh.motion[1, 3:6], [90, 90, 0])  # rotations stay degrees
    trans = bvh.translations()
    np.testing.assert_allclose(trans[1, 2], [0.1, 0.05, 0])  # Yposition replaces the offset's y only
    np.testing.assert_allclose(trans[1, 4], [-0.2, 0, 0])
    rot = bvh.rotations()
    np.testing.assert_allclose(rot[:, [0, 3, 5]], np.broadcast_to(np.eye(3), (2, 3, 3, 3)))
    np.testing.assert_allclose(rot[1, 1], [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-12)  # Rx(90) @ Ry(90)


def test_synthetic_forward_kinematics(synth: Path) -> None:
    bvh = read_bvh(synth)
    np.testing.assert_allclose(forward_kinematics(bvh), SYNTH_EXPECTED, atol=1e-12)
    np.testing.assert_allclose(forward_kinematics(bvh, slice(1, 2)), SYNTH_EXPECTED[1:], atol=1e-12)
    as_metres = read_bvh(synth, unit="m")  # the same numbers read as metres: everything 100x
    assert as_metres.unit == "m"
    np.testing.assert_allclose(forward_kinematics(as_metres), SYNTH_EXPECTED * 100, atol=1e-10)
    np.testing.assert_allclose(forward_kinematics(read_bvh(synth, unit="mm")), SYNTH_EXPECTED / 10, atol=1e-12)


def test_unit_detection(tmp_path: Path) -> None:
    def height(h: float) -> str:  # a root with just an End Site h above it
        text = (f"HIERARCHY\nROOT r\n{{\nOFFSET 0 0 0\nCHANNELS 1 Yposition\nEnd Site\n{{\nOFFSET 0 {h} 0\n}}\n}}\n"
                "MOTION\nFrames: 1\nFrame Time: 0.1\n7\n")
        return read_bvh(_write(tmp_path / "h.bvh", text)).unit
    assert (height(1.7), height(170), height(1700)) == ("m", "cm", "mm")
    with pytest.raises(SMFError, match="unknown unit"):
        read_bvh(tmp_path / "h.bvh", unit="furlong")


def test_rotations_match_scipy_for_any_order(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    for order in ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"):
        text = SYNTH.replace("CHANNELS 3 Xrotation Yrotation Zrotation",
                             "CHANNELS 3 " + " ".join(f"{a}rotation" for a in order))
        bvh = read_bvh(_write(tmp_path / f"{order}.bvh", text))
        bvh.motion[:, 3:6] = rng.uniform(-180, 180, (2, 3))
        expected = Rotation.from_euler(order, bvh.motion[:, 3:6], degrees=True).as_matrix()  # intrinsic
        np.testing.assert_allclose(bvh.rotations()[:, 1], expected, atol=1e-12)


# ---------------------------------------------------------------- malformed files


def _error(tmp_path: Path, text: str, name: str = "bad.bvh") -> str:
    path = _write(tmp_path / name, text)
    with pytest.raises(MotionFormatError) as info:
        read_bvh(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert re.match(rf"{re.escape(str(path))}:\d+: ", msg), msg
    return msg


def test_malformed_hierarchy(tmp_path: Path) -> None:
    assert _error(tmp_path, "\n".join(SYNTH_LINES[:20]) + "\n\n").endswith(":20: file ends inside the HIERARCHY block")
    lines = list(SYNTH_LINES)
    lines[7] = "\t\tFOO 1 2 3"
    assert _error(tmp_path, "\n".join(lines)).endswith(":8: unexpected token 'FOO'")
    assert ":7: expected '{', got 'OFFSET'" in _error(tmp_path, "\n".join(SYNTH_LINES[:6] + SYNTH_LINES[7:]))
    assert ":4: expected '{', got 'OFFSET'" in _error(tmp_path, SYNTH.replace("root\n{", "root\n"))
    assert ":38: unexpected token '}'" in _error(tmp_path, SYNTH.replace("}\n\nMOTION", "}\n}\nMOTION"))
    assert "bad.bvh:1: expected 'HIERARCHY', got 'ROOT'" in _error(tmp_path, SYNTH.replace("HIERARCHY\n", ""))
    assert ":8: expected a number after OFFSET, got 'x'" in _error(tmp_path, SYNTH.replace("OFFSET  0 10 0", "OFFSET 0 x 0"))
    assert ":9: unknown channel 'Wrotation'" in _error(tmp_path, SYNTH.replace("Xrotation Y", "Wrotation Y"))
    assert "more than one ROOT" in _error(tmp_path, SYNTH.replace("\n\nMOTION", "\nROOT r2\n{\n}\nMOTION"))
    assert "missing MOTION" in _error(tmp_path, SYNTH.split("MOTION")[0])


def test_malformed_motion(tmp_path: Path) -> None:
    n = len(SYNTH_LINES)  # the last frame is on line n
    body = "\n".join(SYNTH_LINES)
    assert _error(tmp_path, body[:-9]).endswith(f":{n}: expected 11 values per frame, got 8")  # cut mid-line
    msg = _error(tmp_path, "\n".join(SYNTH_LINES[:-1]))  # truncated: one frame missing
    assert msg.endswith(f":{n - 3}: 'Frames: 2' but 1 frames follow")
    assert "'Frames: 2' but 3 frames follow" in _error(tmp_path, body + "\n" + SYNTH_LINES[-1])
    assert _error(tmp_path, body + " 7").endswith(f":{n}: expected 11 values per frame, got 12")
    assert _error(tmp_path, body.replace("0 -20", "0 abc")).endswith(f":{n}: non-numeric value 'abc'")
    assert _error(tmp_path, body.replace("0 -20", "0 nan")).endswith(f":{n}: non-numeric value 'nan'")
    assert "expected 'Frame Time: <number>'" in _error(tmp_path, body.replace("Frame Time:", "FrameTime:"))
    assert "expected 'Frames: <number>'" in _error(tmp_path, body.replace("Frames:   2", "Frames: two"))
    # bounded before anything is resampled or allocated: frame times of 1-1000 fps, values finite and at most 1e6
    for bad in ("1e8", "1e308", "1e-9", "100000"):
        assert "must be between 0.001 and 1 s" in _error(tmp_path, body.replace("0.05", bad))
    assert _error(tmp_path, body.replace("0 -20", "0 1e300")).endswith(f":{n}: value '1e300' is beyond +-1e+06")
    assert _error(tmp_path, body.replace("0 -20", "0 -1e308")).endswith(f":{n}: value '-1e308' is beyond +-1e+06")
    assert _error(tmp_path, body.replace("0 -20", "0 inf")).endswith(f":{n}: non-numeric value 'inf'")


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(SMFError, match="no such file: .*nope.bvh"):
        read_bvh(tmp_path / "nope.bvh")


def test_empty_motion(tmp_path: Path) -> None:
    text = SYNTH.split("MOTION")[0] + "MOTION\nFrames: 0\nFrame Time: 0.1\n"
    bvh = read_bvh(_write(tmp_path / "empty.bvh", text, crlf=False))
    assert bvh.motion.shape == (0, 11) and forward_kinematics(bvh).shape == (0, 6, 3)


# ---------------------------------------------------------------- real Bandai-Namco data


def test_read_real_bandai(bandai_bvh_files: list[Path]) -> None:
    for path in bandai_bvh_files:
        bvh = read_bvh(path)
        assert bvh.names == BANDAI_JOINTS and bvh.parents[0] == -1 and len(bvh.names) == 22
        assert all(ch == BANDAI_CHANNELS for ch in bvh.channels)
        assert bvh.unit == "cm" and bvh.fps == pytest.approx(30, abs=1e-3)
        assert bvh.motion.shape == (bvh.num_frames, 22 * 6) and bvh.num_frames > 30
        pos = forward_kinematics(bvh)
        assert pos.shape == (bvh.num_frames, 22, 3)
        body = pos[:, 1:]  # joint_Root is a placement joint, not part of the body
        floor = body[..., 1].min(axis=1)  # Y up
        lowest = body[..., 1].argmin(axis=1) + 1
        assert np.isin(lowest, [16, 17, 20, 21]).mean() > 0.95  # feet/toes are the lowest points
        head = body[:, 4, 1] - floor  # the Head joint sits at the base of the skull
        assert 1.2 < np.median(head) < 1.9, np.median(head)
        assert 0.75 < np.median(body[:, 0, 1] - floor) < 1.15  # hips
        # Rigid bones: every parent-child distance is constant and equals the offset length.
        bones = np.linalg.norm(pos[:, 2:] - pos[:, bvh.parents[2:]], axis=-1)
        np.testing.assert_allclose(bones, np.broadcast_to(np.linalg.norm(bvh.offsets[2:], axis=-1), bones.shape),
                                   atol=1e-6)


def test_real_round_trip(bandai_bvh_files: list[Path], tmp_path: Path) -> None:
    """Write a real clip back (joint_Root folded into Hips, which carries the root motion) and re-read it."""
    bvh = read_bvh(bandai_bvh_files[0])
    pos = forward_kinematics(bvh)
    # Non-root position channels just repeat the offsets (to ~1e-7 m), so offsets suffice below.
    np.testing.assert_allclose(bvh.translations()[:, 2:], np.broadcast_to(bvh.offsets[2:], pos[:, 2:].shape),
                               atol=1e-6)
    rot = bvh.rotations()[:, 1:].copy()
    rot[:, 0] = bvh.rotations()[:, 0] @ rot[:, 0]
    out = tmp_path / "round.bvh"
    write_bvh(out, names=bvh.names[1:], parents=bvh.parents[1:] - 1, offsets=bvh.offsets[1:], rotations=rot,
              root_positions=pos[:, 1], frame_time=bvh.frame_time,
              end_sites={j - 1: v for j, v in bvh.end_sites.items()})
    again = read_bvh(out)
    assert again.unit == "m" and again.names == bvh.names[1:] and again.num_frames == bvh.num_frames
    assert again.frame_time == pytest.approx(bvh.frame_time)
    assert again.channels[0] == BANDAI_CHANNELS and again.channels[1] == ["Zrotation", "Xrotation", "Yrotation"]
    np.testing.assert_allclose(forward_kinematics(again), pos[:, 1:], atol=1e-4)


# ---------------------------------------------------------------- writer


def _random_skeleton(rng: np.random.Generator, frames: int = 5):
    parents = np.array([-1, 0, 0, 1, 2, 3])  # breadth-first: written depth-first as 0 1 3 5 2 4
    offsets = rng.normal(size=(6, 3)) * 0.2
    rot = Rotation.random(frames * 6, random_state=1).as_matrix().reshape(frames, 6, 3, 3)
    root = rng.normal(size=(frames, 3))
    return [f"j{i}" for i in range(6)], parents, offsets, rot, root


def _fk(parents, offsets, rot, root) -> np.ndarray:
    """Reference FK with a per-frame Python loop."""
    out = np.zeros(root.shape[:1] + offsets.shape)
    for f in range(len(root)):
        glob = [None] * len(parents)
        for j, p in enumerate(parents):
            glob[j] = rot[f, j] if p < 0 else glob[p] @ rot[f, j]
            out[f, j] = root[f] if p < 0 else out[f, p] + glob[p] @ offsets[j]
    return out


@pytest.mark.parametrize("order", ["ZXY", "XYZ", "yzx"])
def test_write_read_matches_reference_fk(tmp_path: Path, order: str) -> None:
    names, parents, offsets, rot, root = _random_skeleton(np.random.default_rng(2))
    write_bvh(tmp_path / "w.bvh", names=names, parents=parents, offsets=offsets, rotations=rot,
              root_positions=root, frame_time=0.05, order=order)
    bvh = read_bvh(tmp_path / "w.bvh", unit="m")
    perm = [0, 1, 3, 5, 2, 4]
    assert bvh.names == [names[i] for i in perm] and bvh.parents.tolist() == [-1, 0, 1, 2, 0, 4]
    assert bvh.channels[1] == [f"{a}rotation" for a in order.upper()]
    np.testing.assert_allclose(bvh.rotations(), rot[:, perm], atol=1e-6)
    np.testing.assert_allclose(forward_kinematics(bvh), _fk(parents, offsets, rot, root)[:, perm], atol=1e-5)
    # Default End Sites on the leaves (j5, j4): 5 cm along the joint's own offset.
    for j, src in ((3, 5), (5, 4)):
        np.testing.assert_allclose(bvh.end_sites[j], offsets[src] / np.linalg.norm(offsets[src]) * 0.05, atol=1e-6)


def test_write_quaternions_equal_matrices(tmp_path: Path) -> None:
    names, parents, offsets, rot, root = _random_skeleton(np.random.default_rng(3))
    quat = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]].reshape(5, 6, 4)  # w, x, y, z
    quat[::2] *= -1  # q and -q are the same rotation
    kw = dict(names=names, parents=parents, offsets=offsets, root_positions=root, frame_time=1 / 30)
    write_bvh(tmp_path / "m.bvh", rotations=rot, **kw)
    write_bvh(tmp_path / "q.bvh", rotations=quat, **kw)
    a, b = read_bvh(tmp_path / "m.bvh"), read_bvh(tmp_path / "q.bvh")
    np.testing.assert_allclose(a.motion, b.motion, atol=1e-5)
    np.testing.assert_allclose(forward_kinematics(a), forward_kinematics(b), atol=1e-7)


def test_write_rejects_bad_shapes(tmp_path: Path) -> None:
    names, parents, offsets, rot, root = _random_skeleton(np.random.default_rng(4))
    kw = dict(names=names, parents=parents, offsets=offsets, frame_time=0.1)
    with pytest.raises(MotionFormatError, match="root_positions"):
        write_bvh(tmp_path / "x.bvh", rotations=rot, root_positions=root[:-1], **kw)
    with pytest.raises(MotionFormatError, match="rotations"):
        write_bvh(tmp_path / "x.bvh", rotations=rot[:, :, :2], root_positions=root, **kw)
    with pytest.raises(MotionFormatError, match="parents"):
        write_bvh(tmp_path / "x.bvh", rotations=rot, root_positions=root, **{**kw, "parents": [-1, 0, 0, 4, 2, 3]})
    with pytest.raises(MotionFormatError, match="zero-norm"):
        write_bvh(tmp_path / "x.bvh", rotations=np.zeros((5, 6, 4)), root_positions=root, **kw)
    assert not (tmp_path / "x.bvh").exists()


def test_bvh_dataclass_defaults() -> None:
    bvh = BVH(names=["r"], parents=np.array([-1]), offsets=np.zeros((1, 3)), channels=[["Yposition"]],
              end_sites={}, frame_time=0.5, motion=np.array([[1.0], [2.0]]))
    assert bvh.unit == "m" and bvh.fps == 2 and bvh.num_frames == 2
    np.testing.assert_allclose(forward_kinematics(bvh)[:, 0, 1], [1, 2])


def test_the_command_line_refuses_unbounded_bvh_in_one_line_within_bounded_memory(tmp_path: Path) -> None:
    """`smf convert` of a BVH whose frame time or values would blow up resampling or the joints: one line, exit 2,
    under a 1.5 GB address-space cap (a Frame Time of 1e8 s once asked for 15 GB)."""
    import resource
    import subprocess
    import sys

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (1536 << 20, 1536 << 20))

    body = SYNTH.replace("\r\n", "\n")
    for old, new, why in (("0.05", "1e8", "Frame Time"), ("0.05", "1e308", "Frame Time"), ("0.05", "1e-9", "Frame Time"),
                          ("0 -20", "0 1e300", "beyond"), ("0 -20", "0 nan", "non-numeric")):
        path = _write(tmp_path / "bad.bvh", body.replace(old, new))
        run = subprocess.run([sys.executable, "-m", "stablemofusion.cli.main", "convert", str(path),
                              str(tmp_path / "out.npy")], capture_output=True, text=True, timeout=120, preexec_fn=cap)
        assert run.returncode == 2 and why in run.stderr and len(run.stderr.strip().splitlines()) == 1, run.stderr
        assert not (tmp_path / "out.npy").exists()
