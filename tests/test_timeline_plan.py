"""Long and multi-prompt motions: parsing, window planning, and one continuous motion with known joins."""

import numpy as np
import pytest

from stablemofusion.cli.main import main
from stablemofusion.core.errors import SMFError
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.core.timeline_plan import TAIL, check_timeline, parse_timeline, plan_windows


def test_parse_timeline():
    assert parse_timeline("walk forward:4; wave both hands: 3.5 ;bow:2;") == [
        ("walk forward", 4.0), ("wave both hands", 3.5), ("bow", 2.0)]
    assert parse_timeline("look at 12:30 then sit:3") == [("look at 12:30 then sit", 3.0)]
    for bad, msg in [("walk", "not 'PROMPT:SECONDS'"), (":4", "not 'PROMPT:SECONDS'"), ("walk:x", "not a number"),
                     (" ; ", "empty")]:
        with pytest.raises(SMFError, match=msg):
            parse_timeline(bad)


def test_a_timeline_is_checked_before_the_model_loads(tmp_path, capsys):
    """Lengths, counts and the total against the limits without a model: the command line refuses
    'walk:1e308' in one line (a folder that is no model would be the error if it loaded first)."""
    for bad, msg in [("walk:1e308", "at most 120 s"), ("walk:0", "more than 0"), ("walk:60; run:61", "total"),
                     (";".join(["walk:1"] * 17), "1 to 16 segments")]:
        with pytest.raises(SMFError, match=msg):
            check_timeline(parse_timeline(bad))
    assert main(["generate", "--timeline", "a person walks:1e308", "--checkpoint", str(tmp_path), "--out",
                 str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "at most 120 s, got 1e+308" in err and len(err.strip().splitlines()) == 1


def test_windows_cover_every_frame_once():
    windows = plan_windows([("walk", 400), ("bow", 30)], max_frames=196, overlap=20, min_frames=40)
    assert windows[0].keep == 0 and all(w.keep == 20 for w in windows[1:])
    assert all(w.frames <= 196 for w in windows) and all(w.tail == TAIL for w in windows)
    assert sum(w.new for w in windows if w.segment == 0) == 400 and sum(w.new for w in windows if w.segment == 1) == 30
    short_first = plan_windows([("jump", 10), ("walk", 80)], max_frames=196, overlap=20, min_frames=40)
    assert [w.keep for w in short_first] == [0, 10]  # keeps what there is
    with pytest.raises(SMFError, match="at least one frame"):
        plan_windows([("walk", 0)], 196, 20, 40)
    with pytest.raises(SMFError, match="overlap"):
        plan_windows([("walk", 10)], 196, 196, 40)


@pytest.fixture(scope="module")
def pipe():
    return MotionPipeline.from_pretrained(device="cpu")


def test_timeline_is_one_continuous_motion(pipe):
    segments = [("a person walks forward", 8.0), ("a person waves both hands", 6.0), ("a person bows", 6.0)]
    r = pipe.timeline(segments, seed=0)
    assert r.joints.shape == (400, 22, 3) and r.features.shape == (400, 263)
    v = (r.joints[1:] - r.joints[:-1]) * 20
    dv = np.linalg.norm(v[1:] - v[:-1], axis=-1).max(-1)  # (T-2,) largest velocity change per frame
    joins = [160, 280]
    near = np.zeros(len(dv), dtype=bool)
    for j in joins:
        near[j - 8:j + 6] = True
    assert max(dv[j - 3:j + 1].max() for j in joins) <= dv[~near].max()  # no join jumps more than the inside
    walked = np.linalg.norm(r.joints[159, 0, [0, 2]] - r.joints[0, 0, [0, 2]])
    assert walked > 3.0  # 8 s of walking goes somewhere (9 m when written)
    # the root path does not jump at the joins either
    step = np.linalg.norm(r.joints[1:, 0, [0, 2]] - r.joints[:-1, 0, [0, 2]], axis=-1)  # (T-1,) metres per frame
    inside = np.ones(len(step), dtype=bool)
    for j in joins:
        inside[j - 8:j + 6] = False
    assert max(step[j - 2:j + 2].max() for j in joins) <= step[inside].max()  # no larger than a step inside


def test_short_first_segments_and_samplers_without_a_fast_form(pipe):
    r = pipe.timeline([("a person jumps", 0.5), ("a person walks forward", 3.0)], seed=0, steps=2)
    assert len(r.joints) == 70 and isinstance(r.seed, int)
    with pytest.raises(SMFError, match="window by window"):
        pipe("a person walks", seconds=15, sampler="ddpm")
    a, b = pipe.timeline([("a person walks", 12.0)], steps=2), pipe.timeline([("a person walks", 12.0)], steps=2)
    assert a.seed != b.seed or not np.array_equal(a.joints, b.joints)  # no seed: a fresh one, reported


def test_generate_timeline_cli(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["generate", "--timeline", "walk forward:3; bow:2", "--format", "npy", "--out", str(out),
                 "--steps", "4"]) == 0
    joints = np.load(next(out.glob("*_joints.npy")))
    assert joints.shape == (100, 22, 3)
    assert main(["generate", "--timeline", "walk forward", "--out", str(out)]) == 2
    assert main(["generate", "a person walks", "--timeline", "walk:3", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "not 'PROMPT:SECONDS'" in err and "give one of" in err
