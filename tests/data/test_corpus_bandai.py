"""Corpus building on a handful of real Bandai-Namco clips."""

import json
import subprocess
import sys

import numpy as np
import pytest

from stablemofusion.cli.main import main
from stablemofusion.data.corpus_bandai import build_corpus, find_clips, segment_bounds
from stablemofusion.data.dataset import MotionTextDataset
from stablemofusion.data.layout import MotionLayout, read_texts
from stablemofusion.motion.features import canonicalize, features_from_joints, joints_from_features, mirror_joints
from stablemofusion.motion.retarget import JointMap, retarget_bvh


@pytest.fixture(scope="module")
def corpus(bandai_mini_source, tmp_path_factory):
    out = tmp_path_factory.mktemp("corpus")
    stats = build_corpus(bandai_mini_source, out, workers=1)
    return out, stats


def heading(joints):
    """Unwrapped body heading (radians, about +Y, 0 = facing +Z) per frame, from hips and shoulders."""
    across = (joints[:, 2] - joints[:, 1]) + (joints[:, 17] - joints[:, 16])  # towards the right side
    forward = np.cross([0.0, 1.0, 0.0], across)
    return np.unwrap(np.arctan2(forward[:, 0], forward[:, 2]))


def test_retarget_features_back_to_joints_within_a_millimetre(bandai_mini_source):
    for clip in find_clips(bandai_mini_source / "dataset")[:3]:
        joints = retarget_bvh(clip.path, JointMap.builtin("bandai-namco"))
        assert joints.shape[1:] == (22, 3)
        back = joints_from_features(features_from_joints(joints, uniform=False))
        assert np.abs(back - canonicalize(joints, uniform=False)[:-1]).max() < 1e-3
        back = joints_from_features(features_from_joints(joints))
        assert np.abs(back - canonicalize(joints)[:-1]).max() < 1e-3


def test_conventions_on_data_left_is_plus_x_and_walks_forward(bandai_mini_source):
    clip = next(c for c in find_clips(bandai_mini_source / "dataset") if c.name == "dataset-1_walk_normal_001")
    canon = canonicalize(retarget_bvh(clip.path, JointMap.builtin("bandai-namco")))
    assert (canon[:, 1, 0] > canon[:, 2, 0]).mean() > 0.9  # left hip at +X while facing +Z at the start
    assert canon[20, 0, 2] > 0.3  # after one second the root has moved forward (+Z), not backwards


def test_mirror_of_turn_left_turns_right(bandai_mini_source):
    clip = next(c for c in find_clips(bandai_mini_source / "dataset") if c.content == "walk-turn-left")
    joints = retarget_bvh(clip.path, JointMap.builtin("bandai-namco"))
    turn = heading(joints)[-1] - heading(joints)[0]
    assert turn > np.deg2rad(45)  # a left turn increases the heading (towards +X, the character's left)
    mirrored = mirror_joints(joints)
    assert heading(mirrored)[-1] - heading(mirrored)[0] < -np.deg2rad(45)


def test_corpus_layout_texts_mirrors_and_splits(corpus):
    out, stats = corpus
    layout = MotionLayout(out).validate()
    ids = layout.ids("all")
    assert len(ids) == 2 * stats["motions"] and all(("M" + i) in ids for i in ids if not i.startswith("M"))
    for i in ids:
        f = layout.load_features(i)
        assert f.shape[1] == 263 and 2 <= len(f) <= 196
        assert layout.load_joints(i).shape == (len(f), 22, 3)
    # mirrored words: a wave-left-hand clip's mirror talks about the right hand
    rows = [line.split(",") for line in (out / "clips.csv").read_text().splitlines()[1:]]
    wave_id = next(r[0] for r in rows if r[3] == "wave-left-hand")
    orig = read_texts(out / "texts" / f"{wave_id}.txt")
    mirr = read_texts(out / "texts" / f"M{wave_id}.txt")
    assert len(orig) == len(mirr) >= 3 and len({c.caption for c in orig}) == len(orig)
    assert any("left" in c.caption for c in orig) and not any("left" in c.caption for c in mirr)
    assert all(c.caption.replace("left", "right") == m.caption for c, m in zip(orig, mirr) if "left" in c.caption)
    # a clip, its segments and their mirrors stay in one split; every label pair is in train
    split_of = {i: s for s in ("train", "val", "test") for i in layout.ids(s)}
    for r in rows:
        assert split_of[r[0]] == split_of["M" + r[0]] == r[7]
    by_clip = {}
    for r in rows:
        by_clip.setdefault(r[1], set()).add(r[7])
    assert all(len(s) == 1 for s in by_clip.values())
    train_pairs = {(r[2], r[3], r[4]) for r in rows if r[7] == "train"}
    assert train_pairs == {(r[2], r[3], r[4]) for r in rows}
    assert stats["split_sizes"]["test"] >= 2  # the labels with two clips give one to test


def test_sanity_figures(corpus):
    out, stats = corpus
    saved = json.loads((out / "stats.json").read_text())
    assert saved == json.loads(json.dumps(stats))
    assert stats["clips"] == 7 and stats["frames"] > 0 and stats["hours"] > 0 and stats["captions"] > 0
    assert stats["bone_length_std_within_clip_cm"]["max"] < 1.0
    sp = stats["mean_root_speed_m_s"]
    assert sp["walk"] < sp["run"] < sp["dash"]


def test_dataset_loads_the_corpus(corpus):
    out, _ = corpus
    ds = MotionTextDataset(out, "train", seed=0)
    item = ds[0]
    assert item["motion"].shape == (196, 263) and item["length"] % 4 == 0 and item["caption"]


def test_idempotent(corpus, bandai_mini_source):
    out, stats = corpus
    probe = out / "new_joint_vecs" / "000000.npy"
    before = probe.stat().st_mtime_ns
    again = build_corpus(bandai_mini_source, out, workers=1)
    assert again == stats and probe.stat().st_mtime_ns == before


def test_segment_bounds():
    assert segment_bounds(100) == [(0, 100)]
    segs = segment_bounds(500)
    assert len(segs) == 3 and segs[0][0] == 0 and segs[-1][1] == 500 and max(b - a for a, b in segs) <= 196


def test_prepare_bvh_with_joint_map(bandai_mini_source, tmp_path):
    src = tmp_path / "mine"
    src.mkdir()
    for clip in find_clips(bandai_mini_source / "dataset")[:2]:
        (src / clip.path.name).write_bytes(clip.path.read_bytes())
    (src / f"{clip.path.stem}.txt").write_text("a person runs forward\n")
    from importlib import resources
    jmap = resources.files("stablemofusion") / "assets" / "joint_maps" / "bandai-namco.json"
    assert main(["prepare", "bvh", str(src), "--joint-map", str(jmap), "--out", str(tmp_path / "c")]) == 0
    layout = MotionLayout(tmp_path / "c").validate()
    assert len(layout.ids("all")) == 2
    assert read_texts(tmp_path / "c" / "texts" / f"{clip.path.stem}.txt")[0].caption == "a person runs forward"


def test_malformed_bvh_names_file_and_line(bandai_mini_source, tmp_path):
    src = tmp_path / "bad"
    src.mkdir()
    good = find_clips(bandai_mini_source / "dataset")[0].path.read_text().splitlines()
    (src / "cut.bvh").write_text("\n".join(good[:-3] + [good[-3][: len(good[-3]) // 2]]) + "\n")
    jmap = tmp_path / "map.json"
    from importlib import resources
    jmap.write_text((resources.files("stablemofusion") / "assets" / "joint_maps" / "bandai-namco.json").read_text())
    proc = subprocess.run([sys.executable, "-m", "stablemofusion.cli.main", "prepare", "bvh", str(src), "--joint-map",
                           str(jmap), "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert proc.returncode == 2
    err = [ln for ln in proc.stderr.replace("\r", "\n").splitlines() if ln.startswith("smf:")]  # minus the progress bar
    assert len(err) == 1 and "cut.bvh:152: expected 132 values per frame" in err[0] and "Traceback" not in proc.stderr
    assert not (tmp_path / "o" / "Mean.npy").exists()


def test_bad_joint_map(tmp_path, bandai_mini_source):
    (tmp_path / "map.json").write_text('{"joints": {"pelvis": "Hips"}}')
    code = main(["prepare", "bvh", str(bandai_mini_source), "--joint-map", str(tmp_path / "map.json"), "--out",
                 str(tmp_path / "o")])
    assert code == 2
