"""Caption augmentation: seeded, never empty, keeps side and direction words, swaps synonyms."""

import random

from stablemofusion.data.augment import AugmentConfig, augment_caption, synonym_groups

ALL = AugmentConfig(synonym=1.0, dropout=1.0, word_drop=0.5, typo=1.0, casing=1.0)


def test_seeded_and_never_empty():
    caption = "A tired man raises his left hand slowly."
    a = [augment_caption(caption, random.Random(s), None, ALL) for s in range(50)]
    assert a == [augment_caption(caption, random.Random(s), None, ALL) for s in range(50)]
    assert all(len(x.split()) >= 2 for x in a)
    assert len(set(a)) > 10


def test_side_and_direction_words_survive():
    caption = "Someone walks backward and waves the left hand, then turns rightward counterclockwise."
    for s in range(200):
        words = augment_caption(caption, random.Random(s), None, ALL).lower().split()
        for keep in ("backward", "left", "rightward", "counterclockwise"):
            assert any(w.strip(".,") == keep for w in words), (keep, words)


def test_synonym_swap_uses_the_groups():
    table = synonym_groups([["tired", "weary", "exhausted"], ["happily"], ["in a happy way", "cheerfully"]])
    assert table["tired"] == ("exhausted", "weary") and "happily" not in table and "cheerfully" not in table
    only_syn = AugmentConfig(synonym=1.0, dropout=0.0, typo=0.0, casing=0.0)
    out = {augment_caption("A tired man walks.", random.Random(s), table, only_syn) for s in range(40)}
    assert out == {"A weary man walks.", "A exhausted man walks."}


def test_no_augmentation_is_identity():
    none = AugmentConfig(synonym=0.0, dropout=0.0, typo=0.0, casing=0.0)
    assert augment_caption("A man walks forward.", random.Random(0), {"man": ("guy",)}, none) == "A man walks forward."


def test_slowed_features_play_the_same_motion_slower(hml_ref):
    """Factor 1 gives back the features (the decode/encode round trip is exact up to rounding); factor 2 gives
    twice the frames whose decoded joints are the original joints resampled in time, root velocities halved."""
    import numpy as np
    import pytest

    from stablemofusion.data.augment import slowed_features
    from stablemofusion.motion.features import joints_from_features
    from stablemofusion.motion.resample import resample

    feats = np.load(hml_ref / "new_joint_vecs" / "012314.npy").astype(np.float64)
    T = len(feats)
    same = slowed_features(feats, 1.0)
    assert same.shape == (T - 1, 263) and np.abs(same - feats[:-1]).max() < 0.02
    slow = slowed_features(feats, 2.0)
    assert slow.shape == (2 * (T - 1), 263) and np.isfinite(slow).all()
    want = resample(joints_from_features(feats), 1.0, 2.0)[:-1]
    err = np.abs(joints_from_features(slow) - want)
    assert err[:, 0].max() < 1e-3 and err.mean() < 0.005 and err.max() < 0.06  # metres: bones of in-between
    #                                          frames are shortened by the interpolation, then given their length
    speed = lambda f: np.linalg.norm(f[:, 1:3], axis=-1).mean()  # noqa: E731 - root speed, metres per frame
    assert speed(slow) == pytest.approx(speed(feats) / 2, rel=0.05)
    with pytest.raises(ValueError, match="factor"):
        slowed_features(feats, 0.5)
