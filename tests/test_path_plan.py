"""Paths from words (stablemofusion/core/path_plan.py): the words read, and motions bent to follow them on the shipped
model (its portable graphs): the hips' facing turns as the words say (exactly without cleanup), a planted foot is
turned about, circles close, timelines bend their own segments, and the torch path does the same."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from stablemofusion.footskate.metrics import mean_metrics
from stablemofusion.motion.features import joints_from_features
from stablemofusion.core.path_plan import KINDS, bend, facing, heading_offset, parse_path
from stablemofusion.pipelines.motion_pipeline import MotionPipeline


def hips_turn(joints: np.ndarray) -> float:
    """Degrees (positive: left) the hips' facing turned from the first frame to the last."""
    across = joints[:, 1] - joints[:, 2]
    face = np.cross(across, np.array([0.0, 1.0, 0.0]))
    yaw = np.unwrap(np.arctan2(face[:, 0], face[:, 2]))
    return float(np.degrees(yaw[-1] - yaw[0]))


@pytest.fixture(scope="module")
def pipe():
    return MotionPipeline.from_pretrained(backend="onnx", threads=1)


@pytest.mark.parametrize("prompt, kind, angle, model", [
    ("a woman jogs in a loop", "arc", 360, "a woman jogs"),
    ("walk around in a circle clockwise", "arc", -360, "walk"),
    ("a teenager strolls in a half circle to the right", "arc", -180, "a teenager strolls"),
    ("a man does an about-face", "turn", 180, "a man does an turns left"),
    ("an angry man turns round to the right and stomps", "turn", -180, "an angry man turns right and stomps"),
    ("a man pivots 60 degrees to the left", "turn", 60, "a man turns left"),
    ("she turns right", "turn", -90, "she turns right"),
    ("a soldier marches there and back", "back", 180, "a soldier marches"),
    ("a person zigzags forward", "zigzag", 0, "a person walks forward"),
    ("a child runs zigzagging", "zigzag", 0, "a child runs"),
    ("someone curves to the left while running", "arc", 90, "someone while running"),
    ("a person sidesteps left", "strafe", 0, "a person sidesteps left"),  # the model knows sidesteps: kept
])
def test_path_words_are_read(prompt, kind, angle, model):
    spec = parse_path(prompt)
    assert (spec.kind, spec.angle, spec.prompt) == (kind, angle, model)


def test_prompts_without_path_words_are_left_alone():
    for prompt in ("a person waves both hands", "an old man walks forward slowly", "a person bows", "run"):
        assert parse_path(prompt) is None


def test_a_path_has_a_length_by_gait():
    walk, run = parse_path("a man walks in a circle"), parse_path("a man runs in a circle")
    assert walk.seconds > run.seconds > 0 and parse_path("she turns right").seconds is None


@pytest.mark.parametrize("prompt", ["a man walks in a circle", "a person turns round to the right",
                                    "a soldier marches there and back", "a person zigzags forward",
                                    "a person sidesteps left"])
def test_bent_features_face_where_the_words_say(pipe, prompt):
    """Without cleanup the hips' facing turns by the words' angle: exactly in the bent features, within 3 degrees
    once the rigid stage has fitted the body (it moves the hips a little)."""
    spec = parse_path(prompt)
    r = pipe(prompt, seed=3, footskate="off")[0]
    assert abs(hips_turn(r.joints) - spec.angle) < 3.0


def test_a_path_words_length_spreads_across_seeds_as_the_length_model_spreads_the_prompts(pipe):
    """Path words give their kind's length; each seed takes its own share of it, as the length model spreads the
    prompt's lengths (the seed's level over the median): whole steps, no clamp warning, alone as in a batch; the part
    of a prompt of several parts the same way (its stream); a length given is kept."""
    from stablemofusion.core.final import LengthClampedWarning
    from stablemofusion.core.limits import LENGTH_MULTIPLE
    from stablemofusion.core.noise import length_level
    from stablemofusion.core.sequence_plan import spread_seconds

    prompt, b = "a man walks in a circle", pipe.backend
    spec = parse_path(prompt)
    with warnings.catch_warnings():
        warnings.simplefilter("error", LengthClampedWarning)
        alone = [pipe(prompt, seed=s, footskate="off")[0].frames for s in range(6)]
    batch = [r.frames for r in pipe([prompt] * 6, seed=list(range(6)), footskate="off")]
    assert alone == batch and len(set(alone)) >= 3 and all(f % LENGTH_MULTIPLE == 0 for f in alone)
    mid = b.predict_seconds([prompt], [0.5])[0]
    for s, frames in enumerate(alone):
        at = b.predict_seconds([prompt], [length_level(s, 0)])[0]
        want = spread_seconds(spec.seconds, at, mid, b.fps, b.min_frames, b.max_frames, LENGTH_MULTIPLE)
        assert frames == round(want * b.fps)
    parts = {pipe(f"{prompt} then waves", seed=s, footskate="off")[0].sequence[0][1] for s in range(4)}
    assert len(parts) >= 2
    assert pipe(prompt, seconds=5, seed=1, footskate="off")[0].frames == 100


def test_a_circle_closes_and_with_cleanup_the_turn_stays_close(pipe):
    r = pipe("a man walks in a circle", seed=5)[0]  # footskate post, the default
    xz = r.joints[:, 0, [0, 2]]
    assert np.linalg.norm(xz[-1] - xz[0]) < 1.0
    assert abs(hips_turn(r.joints) - 360) < 30


def test_the_body_turns_about_its_planted_foot(pipe):
    """Bending about the planted foot skates less than turning the body about its root."""
    spec = parse_path("a person turns round")
    raws = [pipe(spec.prompt, seconds=4, seed=k, footskate="off")[0].features for k in range(3)]

    def about_root(f):
        f = f.copy()
        extra = heading_offset(np.array([KINDS.index(spec.kind)]), np.radians([spec.angle]), f[None])[0]
        f[:-1, 0] -= np.diff(extra) / 2.0
        return f

    pivot = mean_metrics([joints_from_features(bend(f, spec)) for f in raws])["skate_ratio"]
    root = mean_metrics([joints_from_features(about_root(f)) for f in raws])["skate_ratio"]
    assert pivot < root
    for f in raws:  # the facing is the same either way
        assert np.allclose(facing(bend(f, spec)[None]), facing(about_root(f)[None]), atol=1e-9)


def test_a_timeline_bends_its_own_segment(pipe):
    """Only the circle's segment turns: the wave after it keeps the facing the circle left it with."""
    r = pipe.timeline([("a person walks in a circle", 6.0), ("a person waves both hands", 3.0)], seed=2,
                      footskate="off")
    assert abs(hips_turn(r.joints[:120]) - 360) < 20
    assert abs(hips_turn(r.joints[125:])) < 30


def test_the_torch_path_bends_the_same(pipe):
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    torch_pipe = MotionPipeline.from_pretrained(device="cpu")
    for prompt in ("a man walks in a circle", "someone jogs there and back"):
        a = pipe(prompt, seed=4)[0].joints
        b = torch_pipe(prompt, seed=4, engine="fast")[0].joints
        assert a.shape == b.shape and np.abs(a - b).max() < 1e-3


SQUARE = [[0.0, 0.0], [0.0, 3.0], [3.0, 3.0], [3.0, 0.0]]


def closest(joints: np.ndarray, points) -> list[float]:
    xz = joints[:, 0, [0, 2]]
    return [float(np.linalg.norm(xz - np.asarray(p), axis=-1).min()) for p in points]


@pytest.mark.parametrize("prompt", ["a person walks", "a person runs"])
def test_an_explicit_path_is_followed_through_every_waypoint(pipe, prompt):
    r = pipe(prompt, path=SQUARE, seed=1)[0]  # footskate post
    assert max(closest(r.joints, SQUARE)) < 0.3
    assert np.allclose(r.joints[0, 0, [0, 2]], SQUARE[0], atol=1e-6)  # it starts at the first point


def test_an_explicit_path_with_times_is_on_time(pipe):
    points, times = [[2.0, 1.0], [5.0, 1.0], [5.0, 4.0]], [0.0, 3.0, 6.0]
    r = pipe("a person walks", path={"points": points, "times": times}, seed=2, footskate="off")[0]
    assert len(r.joints) == 120
    for p, t in zip(points, times):
        assert np.linalg.norm(r.joints[min(int(t * 20), 119), 0, [0, 2]] - p) < 0.3


def test_a_long_explicit_path_is_a_timeline_and_both_runtimes_agree(pipe):
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    loop = [[0.0, 0.0], [0.0, 6.0], [6.0, 6.0], [6.0, 0.0], [0.0, 0.0]]  # 24 m: 20 s of walking
    a = pipe("a person walks", path=loop, seed=3)[0]
    b = MotionPipeline.from_pretrained(device="cpu")("a person walks", path=loop, seed=3, engine="fast")[0]
    assert len(a.joints) == 400 and max(closest(a.joints, loop)) < 0.3
    assert np.abs(a.joints - b.joints).max() < 1e-3


@pytest.mark.parametrize("data, message", [([[0, 0]], "2 to 256"), ([[0, 0], [0, 500]], "200 m"),
                                           ({"points": SQUARE, "times": [0, 2, 1, 3]}, "increasing"),
                                           ({"points": SQUARE, "speed": 2}, "not speed"), ([[0, 0], [0, "x"]], "numbers"),
                                           ([[1e15, 0], [1e15, 3]], "within 200 m of the origin"),
                                           ({"points": [[0, 0], [0, 3]], "times": [0, 1e-9]}, "at most 12 m/s"),
                                           ({"points": SQUARE, "times": [0, 1, 2, 2.01]}, "between points 3 and 4")])
def test_a_bad_path_is_one_clear_error(pipe, data, message):
    from stablemofusion.core.errors import SMFError

    with pytest.raises(SMFError, match=message):
        pipe("a person walks", path=data)


def test_the_command_line_and_the_http_api_take_a_path(pipe, tmp_path):
    import json

    from stablemofusion.cli.main import main
    from stablemofusion.serve import create_app

    from serve.serve_helpers import call

    (tmp_path / "p.json").write_text(json.dumps(SQUARE))
    assert main(["generate", "a person walks", "--path", str(tmp_path / "p.json"), "--seed", "1", "--format", "npy",
                 "--engine", "onnx", "--out", str(tmp_path / "out")]) == 0
    joints = np.load(next((tmp_path / "out").glob("*_joints.npy")))
    assert np.abs(joints - pipe("a person walks", path=SQUARE, seed=1)[0].joints).max() < 1e-4
    ok, bad = call(create_app(pipe, max_streams=0),
                   ("POST", "/v1/generate", {"prompt": "a person walks", "seed": 1, "path": SQUARE}),
                   ("POST", "/v1/generate", {"prompt": "a person walks", "path": [[0, 0]]}))
    assert ok.status_code == 200 and np.abs(np.asarray(ok.json()["joints"]) - joints).max() < 1e-3
    assert bad.status_code == 422 and "2 to 256" in bad.json()["error"]
