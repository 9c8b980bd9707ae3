"""Template captions for the Bandai-Namco labels: tokens, variety, label coverage, mirroring."""

from __future__ import annotations

import re

import pytest

from stablemofusion.data.captions import (
    CONTENTS,
    POS_TAGS,
    STYLES,
    captions_for,
    generate,
    mirror_caption,
    mirror_label,
    mirror_tokens,
)
from stablemofusion.errors import SMFError

D1_CONTENTS = ("walk run dash walk-back walk-left walk-right bow bye guide byebye respond call punch kick slash "
               "dance-long dance-short").split()
D1_STYLES = ("normal happy sad angry proud not-confident masculinity feminine childish old tired active musical "
             "giant chimpira").split()
D2_CONTENTS = ("walk walk-turn-left walk-turn-right run wave-both-hands wave-left-hand wave-right-hand "
               "raise-up-both-hands raise-up-left-hand raise-up-right-hand").split()
D2_STYLES = "active elderly exhausted feminine masculine normal youthful".split()
PAIRS = list(dict.fromkeys([(c, s) for c in D1_CONTENTS for s in D1_STYLES]
                           + [(c, s) for c in D2_CONTENTS for s in D2_STYLES]))

# Every caption of a content must match all of these (word-prefix regexes).
ACTION = {
    "walk": [r"walk|step|strid"],
    "run": [r"run|jog"],
    "dash": [r"dash|sprint|run"],
    "walk-back": [r"backward"],
    "walk-left": [r"walk|step|sidestep|mov", r"left"],
    "walk-right": [r"walk|step|sidestep|mov", r"right"],
    "bow": [r"bow|bend"],
    "bye": [r"goodbye|bye|farewell"],
    "byebye": [r"goodbye|bye", r"both"],
    "guide": [r"way|guid|gestur|direct"],
    "respond": [r"respon|answer|repl"],
    "call": [r"beckon|call|come|over"],
    "punch": [r"punch|fist|jab"],
    "kick": [r"kick"],
    "slash": [r"slash|sword"],
    "dance-long": [r"danc"],
    "dance-short": [r"danc"],
    "walk-turn-left": [r"walk", r"turn", r"left"],
    "walk-turn-right": [r"walk", r"turn", r"right"],
    "wave-both-hands": [r"wav", r"both"],
    "wave-left-hand": [r"wav", r"left"],
    "wave-right-hand": [r"wav", r"right"],
    "raise-up-both-hands": [r"rais|lift|up|put", r"both"],
    "raise-up-left-hand": [r"rais|lift|up|put", r"left"],
    "raise-up-right-hand": [r"rais|lift|up|put", r"right"],
}
_OLD = r"old|elderly|frail|stiff|feebl|slowly|age|hunch"
_TIRED = r"tired|wear|exhaust|sluggish|drained|breath|little energy"
STYLE_WORDS = {
    "happy": r"happ|cheer|joy",
    "sad": r"sad|gloom|deject|sorrow|upset|heavy heart",
    "angry": r"angr|furious|irritat|anger",
    "proud": r"proud|pride|haught|confident|arrogant|held high",
    "not-confident": r"timid|insecure|hesita|unconfident|shy|unsure|nervous|confidence",
    "masculinity": r"masculine|manly|macho",
    "masculine": r"masculine|manly|macho",
    "feminine": r"feminine|grace|daint|ladylike|elegant",
    "childish": r"child|kid|playful",
    "old": _OLD,
    "elderly": _OLD,
    "tired": _TIRED,
    "exhausted": _TIRED,
    "active": r"activ|energ|vigor|lively|brisk",
    "musical": r"musical|theatric|rhythm|stage|performer|showy",
    "giant": r"giant|huge|heav|hulking|ponderous|clums",
    "chimpira": r"cock|thug|swagger|menac|punk|delinquent|tough",
    "youthful": r"youth|young|lively|sprightly|nimbl|teenager",
}
IRREGULAR = {("held", "hold"), ("bent", "bend"), ("feet", "foot"), ("men", "man"), ("women", "woman")}


def _has(pattern: str, text: str) -> bool:
    return re.search(rf"\b(?:{pattern})", text) is not None


def _words(caption: str) -> list[str]:
    """Caption words as HumanML3D tokenises them (hyphens removed, punctuation dropped)."""
    return re.findall(r"[a-z]+", caption.lower().replace("-", ""))


def _inflections(lemma: str) -> set[str]:
    stem = lemma[:-1]
    return {lemma, lemma + "s", lemma + "es", stem + "ies", lemma + "ing", stem + "ing",
            lemma + lemma[-1] + "ing", lemma + "d", lemma + "ed"}


def _matches(word: str, token: str) -> bool:
    lemma, pos = token.rsplit("/", 1)
    if pos in ("NOUN", "VERB"):
        return word in _inflections(lemma) or (word, lemma) in IRREGULAR
    return word == lemma


def _check_tokens(caption: str, tokens: list[str]) -> None:
    for tok in tokens:
        assert re.fullmatch(r"[a-z]+/[A-Z]+", tok), tok
        assert tok.split("/")[1] in POS_TAGS, tok
    words = _words(caption)
    assert len(words) == len(tokens), (caption, tokens)
    for w, t in zip(words, tokens):
        assert _matches(w, t), (caption, w, t)


def test_labels_cover_both_datasets():
    assert set(CONTENTS) == set(D1_CONTENTS) | set(D2_CONTENTS)
    assert set(STYLES) == set(D1_STYLES) | set(D2_STYLES)
    assert CONTENTS["walk"].datasets == (1, 2) and CONTENTS["bow"].datasets == (1,)
    assert STYLES["elderly"].datasets == (2,) and STYLES["normal"].datasets == (1, 2)


def test_deterministic():
    a = captions_for("walk", "tired", seed="dataset-1_walk_tired_001")
    assert a == captions_for("walk", "tired", seed="dataset-1_walk_tired_001")
    assert a != captions_for("walk", "tired", seed="dataset-1_walk_tired_002")
    assert captions_for("kick", "normal", seed=3) == captions_for("kick", "normal", seed=3)
    assert captions_for("kick", "normal", n=3, seed=3) == captions_for("kick", "normal", seed=3)[:3]


def test_count():
    assert captions_for("bow", "happy", n=0) == []
    assert len(set(c for c, _ in captions_for("walk", "normal", n=20, seed=1))) == 20
    with pytest.raises(SMFError):
        captions_for("walk", "normal", n=-1)


@pytest.mark.parametrize("content,style", PAIRS)
def test_pair(content, style):
    for seed in (0, "clip"):
        caps = generate(content, style, n=6, seed=seed)
        texts = [c.text for c in caps]
        assert len(set(texts)) == 6, texts
        assert len({c.form for c in caps}) >= 4, [c.form for c in caps]
        for c in caps:
            _check_tokens(c.text, c.tokens)
            assert c.text.endswith(".") and "  " not in c.text
            for pattern in ACTION[content]:
                assert _has(pattern, c.text), (c.text, pattern)
            for other in ("left", "right"):
                if other not in content:
                    assert not _has(other, c.text), c.text
            # a/an agreement and verb agreement after "is"
            assert not re.search(r"\ba [aeiou]|\ban [^aeiou\W]", c.text), c.text
            assert all(w.endswith("ing") for w in re.findall(r"\bis (\w+)", c.text)), c.text
            assert not re.search(r"\b(person|man|woman|someone|he|she|figure|character) (walk|run|wave|raise)\b",
                                 c.text), c.text
        if style != "normal":
            assert sum(_has(STYLE_WORDS[style], t) for t in texts) >= 5, texts


def test_normal_sometimes_omits_style():
    texts = [c for s in range(5) for c, _ in captions_for("walk", "normal", n=9, seed=s)]
    plain = [t for t in texts if not _has(r"normal|casual|natural|relaxed|ordinary|calm", t)]
    assert 0 < len(plain) < len(texts)


def test_token_example_format():
    text, tokens = captions_for("raise-up-left-hand", "elderly", n=1, seed=0)[0]
    assert "left/ADJ" in tokens
    assert any(t.endswith("/VERB") for t in tokens) and any(t.endswith("/NOUN") for t in tokens)


def test_mirror_caption():
    assert mirror_caption("a person waves his left hand then turns right") == \
        "a person waves his right hand then turns left"
    assert mirror_caption("Left foot, then RIGHT.") == "Right foot, then LEFT."
    assert mirror_caption("turns clockwise, then leftwards") == "turns counterclockwise, then rightwards"
    assert mirror_caption("spins counter-clockwise") == "spins clockwise"
    assert mirror_caption("he stops right away, all right") == "he stops right away, all right"
    assert mirror_caption("a bright, rightful leftover") == "a bright, rightful leftover"
    assert mirror_caption("left-handed") == "right-handed"


def test_mirror_twice_is_identity():
    for content in ("walk-left", "walk-turn-right", "wave-left-hand", "raise-up-right-hand", "walk"):
        for text, tokens in captions_for(content, "normal", n=6, seed=2):
            assert mirror_caption(mirror_caption(text)) == text
            assert mirror_tokens(mirror_tokens(tokens)) == tokens
            mirrored = mirror_caption(text)
            assert (mirrored != text) == ("left" in content or "right" in content)
            _check_tokens(mirrored, mirror_tokens(tokens))


def test_mirror_tokens():
    toks = "a/DET man/NOUN kick/VERB with/ADP his/DET left/ADJ leg/NOUN".split()
    assert mirror_tokens(toks)[5] == "right/ADJ"
    assert mirror_tokens(["turn/VERB", "right/ADV", "away/ADV"]) == ["turn/VERB", "right/ADV", "away/ADV"]
    assert mirror_tokens(["counterclockwise/ADV"]) == ["clockwise/ADV"]


def test_mirror_label():
    pairs = [("walk-left", "walk-right"), ("walk-turn-left", "walk-turn-right"),
             ("wave-left-hand", "wave-right-hand"), ("raise-up-left-hand", "raise-up-right-hand")]
    for a, b in pairs:
        assert mirror_label(a) == b and mirror_label(b) == a
    for c in CONTENTS:
        assert mirror_label(mirror_label(c)) == c
        assert mirror_label(c) in CONTENTS
    assert mirror_label("wave-both-hands") == "wave-both-hands" and mirror_label("walk-back") == "walk-back"


def test_unknown_labels():
    with pytest.raises(SMFError, match=r"unknown content label 'jump'.*walk-back"):
        captions_for("jump", "normal")
    with pytest.raises(SMFError, match=r"unknown style label 'sleepy'.*chimpira"):
        captions_for("walk", "sleepy")
    with pytest.raises(SMFError, match="jump"):
        mirror_label("jump")
