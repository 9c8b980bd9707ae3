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
