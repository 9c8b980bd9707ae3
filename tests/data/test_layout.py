"""MotionLayout, caption lines and feature statistics, on a copy of the reference HumanML3D files."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from stablemofusion.data.layout import (CaptionLine, MotionLayout, format_text_line, mean_std, parse_text_line,
                                        read_texts)
from stablemofusion.core.errors import MotionFormatError, SMFError
from stablemofusion.motion.features import feature_slices, mirror_features
from stablemofusion.motion.skeleton import get_skeleton

IDS = ("000000", "012314")


def make_layout(ref: Path, root: Path) -> Path:
    """Copy the reference motions into ``root``, add a text for 012314, its mirror and the split files."""
    for d in ("new_joints", "new_joint_vecs", "texts"):
        (root / d).mkdir(parents=True)
    for name in ("Mean.npy", "Std.npy", "texts/000000.txt", *(f"{d}/{i}.npy" for d in ("new_joints", "new_joint_vecs")
                                                             for i in IDS)):
        shutil.copyfile(ref / name, root / name)
    (root / "texts/012314.txt").write_text(
        "a person walks forward and turns.#a/DET person/NOUN walk/VERB forward/ADV and/CCONJ turn/VERB#0.0#0.0\n"
        "a person takes a few steps.#a/DET person/NOUN take/VERB a/DET few/ADJ step/NOUN#1.0#4.0\n"
        "too short to keep.#too/ADV short/ADJ to/PART keep/VERB#0.0#1.0\n")
    np.save(root / "new_joint_vecs/M012314.npy", mirror_features(np.load(ref / "new_joint_vecs/012314.npy")))
    shutil.copyfile(root / "texts/012314.txt", root / "texts/M012314.txt")
    lay = MotionLayout(root)
    lay.write_split("train", ["000000", "012314", "M012314"])
    lay.write_split("test", ["000000"])
    lay.write_split("all", ["000000", "012314", "M012314"])
    return root


@pytest.fixture
def layout_dir(hml_ref: Path, tmp_path: Path) -> Path:
    return make_layout(hml_ref, tmp_path / "hml")


def test_real_text_round_trip(hml_ref: Path):
    path = hml_ref / "texts/000000.txt"
    lines = read_texts(path)
    raw = [s for s in path.read_text().splitlines() if s.strip()]
    assert len(lines) == len(raw) == 4
    assert all(c.whole_clip for c in lines)
    assert lines[0].caption == "a man kicks something or someone with his left leg."
    assert lines[0].tokens[:3] == ["a/DET", "man/NOUN", "kick/VERB"]
    assert [format_text_line(c) for c in lines] == raw
    assert [parse_text_line(format_text_line(c)) for c in lines] == lines


def test_parse_text_line_variants():
    c = parse_text_line("a man jumps.#a/DET man/NOUN jump/VERB#1.5#4.0\n")
    assert (c.caption, c.tokens, c.start, c.end, c.whole_clip) == ("a man jumps.", ["a/DET", "man/NOUN", "jump/VERB"],
                                                                   1.5, 4.0, False)
    assert parse_text_line("x#x/X#nan#nan").whole_clip  # the official loader reads NaN as 0
    assert parse_text_line("number #1 move#move/NOUN#0.0#0.0").caption == "number #1 move"
    c = CaptionLine("number #1 move", ["move/NOUN"], 2.0, 3.5)
    assert parse_text_line(format_text_line(c)) == c
    with pytest.raises(MotionFormatError, match=r"t\.txt:3: expected 'caption#tokens#start#end'"):
        parse_text_line("no fields at all", "t.txt:3")
    with pytest.raises(MotionFormatError, match="start time 'soon'"):
        parse_text_line("a#a/DET#soon#0.0")


def test_layout_reads(layout_dir: Path, hml_ref: Path):
    lay = MotionLayout(layout_dir).validate()
    assert lay.skeleton.name == "humanml3d"
    assert lay.ids("train") == ["000000", "012314", "M012314"]
    assert lay.ids("test.txt") == ["000000"]
    assert lay.load_features("000000").shape == (116, 263)
    assert lay.load_features("012314").shape == (170, 263)
    assert lay.load_joints("012314").shape == (170, 22, 3)
    texts = lay.load_texts("012314")
    assert [(c.start, c.end) for c in texts] == [(0.0, 0.0), (1.0, 4.0), (0.0, 1.0)]
    np.testing.assert_array_equal(lay.mean, np.load(hml_ref / "Mean.npy"))
    np.testing.assert_array_equal(lay.std, np.load(hml_ref / "Std.npy"))


def test_mean_std_groups(hml_ref: Path):
    feats = [np.load(hml_ref / f"new_joint_vecs/{i}.npy") for i in IDS]
    mean, std = mean_std(feats, "humanml3d")
    data = np.concatenate(feats)
    np.testing.assert_allclose(mean, data.mean(0))
    per_dim = data.std(0)
    for name, s in feature_slices("humanml3d").items():
        assert np.all(std[s] == std[s][0]), name
        assert std[s][0] == pytest.approx(per_dim[s].mean()), name
    assert std[1] == std[2] and std[4] == std[66] != std[67] and np.all(std[4:67] == std[4])
    assert (std > 0).all()
    # the released Std.npy has the same 7-group structure
    assert len(np.unique(np.load(hml_ref / "Std.npy"))) == 7
    with pytest.raises(MotionFormatError, match="motion 1"):
        mean_std([feats[0], feats[1][:, :250]])


def test_writers_round_trip(tmp_path: Path, hml_ref: Path):
    lay = MotionLayout(tmp_path / "new")
    feats = [np.load(hml_ref / f"new_joint_vecs/{i}.npy") for i in IDS]
    lay.write_mean_std(*mean_std(feats))
    assert MotionLayout(tmp_path / "new").skeleton.name == "humanml3d"
    lay.write_features("a", feats[0])
    lay.write_texts("a", [CaptionLine("a man kicks.", ["a/DET", "man/NOUN", "kick/VERB"], 0.0, 0.0)])
    lay.write_split("train", ["a"])
    lay.validate()
    assert lay.ids("train") == ["a"] and lay.load_texts("a")[0].caption == "a man kicks."
    np.testing.assert_allclose(lay.load_features("a"), feats[0], atol=1e-6)
    kit = MotionLayout(tmp_path / "kit")
    kit.write_mean_std(np.zeros(251), np.ones(251))
    assert MotionLayout(tmp_path / "kit").skeleton.name == "kit"
    assert get_skeleton("kit").feature_dim == len(MotionLayout(tmp_path / "kit").std)
    with pytest.raises(MotionFormatError, match="positive"):
        lay.write_mean_std(np.zeros(263), np.zeros(263))
    with pytest.raises(SMFError, match="invalid motion id"):
        lay.write_split("val", ["ok", "two words"])


def test_missing_mean(layout_dir: Path):
    (layout_dir / "Mean.npy").unlink()
    with pytest.raises(SMFError, match="Mean.npy"):
        MotionLayout(layout_dir).validate()
    with pytest.raises(SMFError, match="Mean.npy"):
        MotionLayout(layout_dir).skeleton


def test_wrong_stats_shape(layout_dir: Path):
    np.save(layout_dir / "Std.npy", np.ones(250, dtype=np.float32))
    with pytest.raises(MotionFormatError, match=r"Std\.npy.*\(263,\)"):
        MotionLayout(layout_dir).validate()
    with pytest.raises(MotionFormatError, match="Mean.npy"):
        MotionLayout(layout_dir, "kit").validate()


def test_missing_split_and_files(layout_dir: Path):
    lay = MotionLayout(layout_dir)
    with pytest.raises(SMFError, match=r"val\.txt"):
        lay.ids("val")
    with pytest.raises(SMFError, match=r"nope\.npy"):
        lay.load_features("nope")
    with pytest.raises(SMFError, match=r"M012314\.npy"):
        lay.load_joints("M012314")
    with pytest.raises(SMFError, match=r"nope\.txt"):
        lay.load_texts("nope")
    shutil.rmtree(layout_dir / "texts")
    with pytest.raises(SMFError, match="texts"):
        lay.validate()


def test_malformed_text_and_features(layout_dir: Path):
    lay = MotionLayout(layout_dir)
    with open(layout_dir / "texts/012314.txt", "a") as f:
        f.write("\nbroken line without fields\n")
    with pytest.raises(MotionFormatError, match=r"012314\.txt:5: expected 'caption#tokens#start#end'"):
        lay.load_texts("012314")
    np.save(layout_dir / "new_joint_vecs/000000.npy", np.zeros((50, 251), np.float32))
    with pytest.raises(MotionFormatError, match=r"000000\.npy.*\(T, 263\)"):
        lay.load_features("000000")
    (layout_dir / "new_joint_vecs/000000.npy").write_bytes(b"not numpy")
    with pytest.raises(MotionFormatError, match=r"000000\.npy: not a readable"):
        lay.load_features("000000")
