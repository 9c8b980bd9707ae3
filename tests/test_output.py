"""stablemofusion.core.output: bytes and files of a MotionResult from one place; never overwrites silently."""

import dataclasses
import io
import json

import numpy as np
import pytest

from stablemofusion.core.errors import SMFError
from stablemofusion.footskate.cleanup import CLEANUP_CONTACTS
from stablemofusion.footskate.contacts import kinematic_contacts
from stablemofusion.motion.features import features_from_joints
from stablemofusion.motion.files import load_motion
from stablemofusion.core.output import (FORMATS, JSON_DECIMALS, OUTPUTS, WRITERS, bvh_text, free_stem, json_bytes,
                                   json_payload, npy_bytes, parse_formats, write_result, write_results, writer)
from stablemofusion.core.result import MotionResult


@pytest.fixture(scope="module")
def result():
    f = features_from_joints(load_motion("example:wave-both-hands").joints)
    return MotionResult.build("a person waves", f, None, "humanml3d", 20.0, 3)


def test_bytes_of_each_format(result):
    joints = np.load(io.BytesIO(npy_bytes(result)))
    assert joints.dtype == np.float32 and joints.shape == result.joints.shape
    assert np.load(io.BytesIO(npy_bytes(result, "features"))).shape == result.features.shape
    assert bvh_text(result).startswith("HIERARCHY")
    body = json_payload(result, steps=10)
    assert list(body)[:5] == ["prompt", "fps", "frames", "seed", "steps"] and body["frames"] == result.frames
    assert np.allclose(body["joints"], result.joints, atol=1e-5)


def test_json_bytes_are_the_compact_json_of_the_rounded_joints(result):
    """Compact one-line UTF-8 JSON whose numbers are the rounded joints exactly (orjson writes 0.00009 where
    the standard library writes 9e-05: the same values)."""
    data = json_bytes(result, steps=10, note="pas à pas")
    rounded = np.round(result.joints, JSON_DECIMALS).tolist()
    planted = kinematic_contacts(result.joints, result.fps, config=CLEANUP_CONTACTS).astype(int).T.tolist()
    expected = {"prompt": result.prompt, "fps": result.fps, "frames": result.frames, "seed": result.seed,
                "steps": 10, "note": "pas à pas", "contacts": planted, "joints": rounded}
    assert json.loads(data) == expected and list(json.loads(data)) == list(expected)
    assert data.endswith(b"\n") and data.count(b"\n") == 1 and b", " not in data and "à".encode() in data
    bad = dataclasses.replace(result, joints=np.full_like(result.joints, np.nan))
    with pytest.raises(SMFError, match="NaN"):
        json_bytes(bad)


def test_files_never_overwrite_silently(result, tmp_path):
    first = write_results([result], tmp_path, ["npy", "json"])[0]
    second = write_results([result], tmp_path, ["npy", "json"])[0]
    assert first != second and second.name == first.name + "-2"
    assert (tmp_path / (second.name + ".json")).is_file() and (tmp_path / (first.name + ".json")).is_file()
    again = write_results([result], tmp_path, ["npy", "json"], overwrite=True)[0]
    assert again == first
    assert free_stem(first, ["bvh"]) == first  # only the files a format writes count


def test_a_new_format_is_one_function(result, tmp_path):
    @writer("txt", ".txt")
    def write_txt(r, stem, meta):
        path = OUTPUTS["txt"](stem)[0]
        path.write_text(r.prompt)
        return [path]

    try:
        assert parse_formats("npy,txt") == ["npy", "txt"]
        paths = write_result(result, tmp_path / "m", ["txt"])
        assert paths[0].read_text() == "a person waves"
    finally:
        WRITERS.pop("txt"), OUTPUTS.pop("txt")
    with pytest.raises(SMFError, match="choose from"):
        parse_formats("npy,txt")
    assert set(FORMATS) == {"npy", "bvh", "json", "glb", "mp4", "gif"}


def test_the_feet_the_cleanup_held_travel_with_the_json_answer():
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    post = pipe("a person walks forward", seconds=3, seed=1)[0]
    held = json_payload(post)["contacts"]
    assert len(held) == 4 and all(len(c) == post.frames for c in held) and 0 < sum(map(sum, held)) < 4 * post.frames
    assert np.array_equal(np.asarray(held, bool).T, post.contacts)
    off = pipe("a person walks forward", seconds=3, seed=1, footskate="off")[0]  # without cleanup: the planted feet
    planted = kinematic_contacts(off.joints, off.fps, config=CLEANUP_CONTACTS)
    assert np.array_equal(np.asarray(json_payload(off)["contacts"], bool).T, planted) and planted.any()
