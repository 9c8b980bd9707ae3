"""MotionTextDataset on a temporary layout built from the reference HumanML3D files."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from stablemofusion.data import MotionLayout, MotionTextDataset, collate
from stablemofusion.core.errors import MotionFormatError, SMFError
from stablemofusion.motion.features import feature_slices, mirror_features

IDS = ("000000", "012314")
WHOLE_012314 = "a person walks forward and turns.#a/DET person/NOUN walk/VERB forward/ADV and/CCONJ turn/VERB#0.0#0.0\n"
SUB_012314 = "a person takes a few steps.#a/DET person/NOUN take/VERB a/DET few/ADJ step/NOUN#1.0#4.0\n"
SHORT_012314 = "too short to keep.#too/ADV short/ADJ to/PART keep/VERB#0.0#1.0\n"  # 20 frames < 40: dropped


@pytest.fixture
def root(hml_ref: Path, tmp_path: Path) -> Path:
    """Reference motions + a text for 012314 (whole clip, 1-4 s sub-clip, a too-short sub-clip), its mirror
    M012314, and split files train (all three), test (000000)."""
    out = tmp_path / "hml"
    for d in ("new_joints", "new_joint_vecs", "texts"):
        (out / d).mkdir(parents=True)
    for name in ("Mean.npy", "Std.npy", "texts/000000.txt", *(f"{d}/{i}.npy" for d in ("new_joints", "new_joint_vecs")
                                                             for i in IDS)):
        shutil.copyfile(hml_ref / name, out / name)
    for mid in ("012314", "M012314"):
        (out / f"texts/{mid}.txt").write_text(WHOLE_012314 + SUB_012314 + SHORT_012314)
    np.save(out / "new_joint_vecs/M012314.npy", mirror_features(np.load(hml_ref / "new_joint_vecs/012314.npy")))
    lay = MotionLayout(out)
    lay.write_split("train", ["000000", "012314", "M012314"])
    lay.write_split("test", ["000000"])
    return out


def items(ds: MotionTextDataset) -> list[dict]:
    return [ds[i] for i in range(len(ds))]


def test_entries_and_shapes(root: Path):
    ds = MotionTextDataset(root, "train", seed=0)
    assert ds.min_frames == 40 and len(ds) == 5  # 3 whole clips + 2 sub-clips (1-4 s); 0-1 s sub-clips dropped
    assert [(ds.ids[e.index], e.start, e.end) for e in ds.entries] == [
        ("000000", 0, 116), ("012314", 0, 170), ("012314", 20, 80), ("M012314", 0, 170), ("M012314", 20, 80)]
    for epoch in range(5):
        ds.set_epoch(epoch)
        for it in items(ds):
            n = it["length"]
            assert it["motion"].shape == (196, 263) and it["motion"].dtype == torch.float32
            assert it["mask"].dtype == torch.bool and it["mask"].sum() == n and it["mask"][:n].all()
            assert n % 4 == 0 and 40 <= n <= 196
            assert torch.all(it["motion"][n:] == 0) and torch.all(it["motion"][:n].abs().sum(-1) > 0)
            assert it["frames"][1] - it["frames"][0] == n
            assert isinstance(it["caption"], str) and it["tokens"] and "/" in it["tokens"][0]


def test_sub_clip_lengths_and_captions(root: Path):
    ds = MotionTextDataset(root, seed=1)
    lengths = set()
    for epoch in range(30):
        ds.set_epoch(epoch)
        it = ds[2]
        a, b = it["frames"]
        assert it["id"] == "012314" and it["caption"] == "a person takes a few steps."
        assert 20 <= a and b <= 80
        lengths.add(it["length"])
        assert ds[0]["length"] in (112, 116)  # 116 frames: 'single' 116 or 'double' 112
    assert lengths == {56, 60}  # 60 frames: both coin outcomes occur
    captions = set()
    for epoch in range(40):
        ds.set_epoch(epoch)
        captions.add(ds[0]["caption"])
    assert len(captions) == 4  # the 4 whole-clip captions of 000000


def test_normalisation_uses_feature_bias(root: Path, hml_ref: Path):
    ds = MotionTextDataset(root, seed=3)
    mean, std = np.load(hml_ref / "Mean.npy"), np.load(hml_ref / "Std.npy")
    it = ds[1]
    a, b = it["frames"]
    raw = np.load(hml_ref / "new_joint_vecs/012314.npy")[a:b]
    x = it["motion"][: b - a].numpy()
    c = feature_slices("humanml3d").contacts.start
    for d, bias in [(0, 5.0), (1, 5.0), (3, 5.0), (10, 1.0), (100, 1.0), (200, 1.0), (c, 5.0), (262, 5.0)]:
        np.testing.assert_allclose(x[:, d], (raw[:, d] - mean[d]) / (std[d] / bias), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ds.denormalize(it["motion"][: b - a]).numpy(), raw, atol=1e-5)
    np.testing.assert_allclose(ds.normalize(ds.denormalize(x)), x, atol=1e-5)
    plain = MotionTextDataset(root, seed=3, feat_bias=1.0)
    np.testing.assert_allclose(plain.std, std)
    np.testing.assert_allclose(plain[1]["motion"][: b - a, 0].numpy(), (raw[:, 0] - mean[0]) / std[0], rtol=1e-5)


def test_reproducible(root: Path):
    def sample(ds):
        return [(it["caption"], it["length"], it["frames"], it["motion"]) for it in items(ds)]

    a, b = sample(MotionTextDataset(root, seed=7)), sample(MotionTextDataset(root, seed=7))
    assert all(x[:3] == y[:3] and torch.equal(x[3], y[3]) for x, y in zip(a, b))
    ds = MotionTextDataset(root, seed=7)
    runs = []
    for epoch in range(8):
        ds.set_epoch(epoch)
        runs.append([it["frames"] for it in items(ds)])
    assert len({tuple(r) for r in runs}) > 1  # epochs draw different crops
    assert len(MotionTextDataset(root)[0]["motion"]) == 196  # seed=None: fresh randomness


def test_max_frames_min_frames_and_ids(root: Path):
    ds = MotionTextDataset(root, seed=0, max_frames=64)
    for it in items(ds):
        assert it["motion"].shape == (64, 263) and it["length"] in (60, 64, 56)
    ds = MotionTextDataset(root, seed=0, min_frames=120)  # 000000 (116) and the 60-frame sub-clips go
    assert [ds.ids[e.index] for e in ds.entries] == ["012314", "M012314"]
    ds = MotionTextDataset(root, ids=["000000"], seed=0)
    assert len(ds) == 1 and ds[0]["id"] == "000000"
    assert len(MotionTextDataset(root, "test")) == 1


def test_short_crops_draw_lengths_from_half_to_all_of_the_clip(root: Path):
    """short_crops=1: every item a random 50-100% of what it would be (at least min_frames, a multiple of 4);
    short_crops=0 (the default) draws exactly what it drew before the option existed."""
    whole, short = MotionTextDataset(root, seed=5), MotionTextDataset(root, seed=5, short_crops=1.0)
    seen = []
    for epoch in range(12):
        whole.set_epoch(epoch)
        short.set_epoch(epoch)
        for a, b in zip(items(whole), items(short)):  # the same coin, so `a` is the length `b` was cut from
            low = min(a["length"], max(40, 4 * -(-a["length"] // 8)))  # half, rounded up to a unit of 4
            assert b["length"] % 4 == 0 and low <= b["length"] <= a["length"]
            seen.append(b["length"] < a["length"])
    assert any(seen)  # some items are cut short
    again = MotionTextDataset(root, seed=5, short_crops=0.0)
    assert [it["frames"] for it in items(again)] == [it["frames"] for it in items(MotionTextDataset(root, seed=5))]
    with pytest.raises(SMFError, match="short_crops"):
        MotionTextDataset(root, short_crops=1.5)


def test_item_with_warp_is_the_motion_played_slower(root: Path):
    """item(i, warp): the same caption and crop coin as item(i), cut from the motion played ``warp`` times slower
    (longer crops of short entries), finite, a multiple of 4, covering source frames consistent with the factor;
    warp 1 is exactly __getitem__; the items are a function of (seed, epoch, index, warp)."""
    plain, warped = MotionTextDataset(root, seed=3), MotionTextDataset(root, seed=3)
    longer = []
    for epoch, w in zip(range(6), (1.2, 1.5, 1.8, 2.0, 1.3, 1.9)):
        plain.set_epoch(epoch)
        warped.set_epoch(epoch)
        for i, e in enumerate(plain.entries):
            a, b = plain[i], warped.item(i, w)
            n = b["length"]
            assert a["warp"] == 1.0 and b["warp"] == w and b["caption"] == a["caption"] and n % 4 == 0 and n <= 196
            assert torch.isfinite(b["motion"]).all() and b["mask"].sum() == n
            start, end = b["frames"]
            assert e.start <= start < end <= e.end and (n - 1) / w <= end - start <= (n - 1) / w + 3
            longer.append(n > e.end - e.start)
            assert torch.equal(warped.item(i, 1.0)["motion"], a["motion"])
    assert any(longer)
    again = MotionTextDataset(root, seed=3)
    again.set_epoch(5)
    assert all(torch.equal(again.item(i, 1.9)["motion"], warped.item(i, 1.9)["motion"]) for i in range(len(again)))
    with pytest.raises(SMFError, match="warp"):
        again.item(0, 0.5)


def test_dataloader_collate(root: Path):
    loader = DataLoader(MotionTextDataset(root, seed=0), batch_size=3, shuffle=False, collate_fn=collate)
    batches = list(loader)
    assert [len(b["id"]) for b in batches] == [3, 2]
    b = batches[0]
    assert b["motion"].shape == (3, 196, 263) and b["mask"].shape == (3, 196)
    assert b["length"].dtype == torch.long and b["frames"].shape == (3, 2)
    assert torch.equal(b["mask"].sum(1), b["length"])
    assert b["id"] == ["000000", "012314", "012314"] and len(b["caption"]) == len(b["tokens"]) == 3


def test_errors(root: Path):
    with pytest.raises(SMFError, match=r"val\.txt"):
        MotionTextDataset(root, "val")
    with pytest.raises(SMFError, match="no motions left"):
        MotionTextDataset(root, min_frames=180)
    with open(root / "texts/M012314.txt", "a") as f:
        f.write("a caption without tokens or times\n")
    with pytest.raises(MotionFormatError, match=r"M012314\.txt:4"):
        MotionTextDataset(root)
    np.save(root / "new_joint_vecs/012314.npy", np.zeros((100, 262), np.float32))
    with pytest.raises(MotionFormatError, match=r"012314\.npy.*\(100, 262\)"):
        MotionTextDataset(root)
    (root / "Mean.npy").unlink()
    with pytest.raises(SMFError, match=r"Mean\.npy"):
        MotionTextDataset(root)
