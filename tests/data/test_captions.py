"""Training captions from the corpus lexicon: label coverage, phrasing minimums, held-out words, tokens,
variety of sentence structures, mirroring."""

from __future__ import annotations

import re

import pytest

from stablemofusion.data.captions import (POS_TAGS, STRUCTURES, captions_for, described_by, generate,
                                          mirror_caption, mirror_label, mirror_tokens, paraphrases, structures_for)
from stablemofusion.data.lexicon import STYLE_KINDS, load_lexicon, marked_verbs, parse_lexicon, verb_forms
from stablemofusion.core.errors import SMFError

LEX = load_lexicon("bandai")
D1_CONTENTS = ("walk run dash walk-back walk-left walk-right bow bye guide byebye respond call punch kick slash "
               "dance-long dance-short").split()
D1_STYLES = ("normal happy sad angry proud not-confident masculinity feminine childish old tired active musical "
             "giant chimpira").split()
D2_CONTENTS = ("walk walk-turn-left walk-turn-right run wave-both-hands wave-left-hand wave-right-hand "
               "raise-up-both-hands raise-up-left-hand raise-up-right-hand").split()
D2_STYLES = "active elderly exhausted feminine masculine normal youthful".split()
PAIRS = list(dict.fromkeys([(c, s) for c in D1_CONTENTS for s in D1_STYLES]
                           + [(c, s) for c in D2_CONTENTS for s in D2_STYLES]))
_STOP = set("a an the of in on with to as if like and is his her their your its one up out at for from".split())


def _words(text: str) -> set[str]:
    return set(re.findall(r"[a-z][a-z'-]*", text.lower()))


_LEFT = {"left", "leftward", "leftwards", "counterclockwise", "counter-clockwise", "anticlockwise"}
_RIGHT = {"right", "rightward", "rightwards", "clockwise"}


def _sides(text: str) -> set[str]:
    w = set(re.findall(r"[a-z]+", re.sub(r"(counter|anti)-", r"\1", text.lower())))
    return ({"left"} if w & _LEFT else set()) | ({"right"} if w & _RIGHT else set())


def _want_side(content: str) -> set[str]:
    return {"left"} if "left" in content else {"right"} if "right" in content else set()


def _style_words(style: str) -> set[str]:
    sw = LEX.style(style)
    return {w for k in STYLE_KINDS for item in sw.kind(k).train for w in _words(item.replace("{pos}", ""))} - _STOP


def test_labels_cover_both_datasets():
    assert set(LEX.datasets[1][0]) == set(D1_CONTENTS) and set(LEX.datasets[2][0]) == set(D2_CONTENTS)
    assert set(LEX.datasets[1][1]) == set(D1_STYLES) and set(LEX.datasets[2][1]) == set(D2_STYLES)
    assert set(LEX.contents) == set(D1_CONTENTS) | set(D2_CONTENTS)
    assert LEX.content_datasets("walk") == (1, 2) and LEX.style_datasets("elderly") == (2,)


@pytest.mark.parametrize("content", sorted(set(D1_CONTENTS) | set(D2_CONTENTS)))
def test_every_content_has_25_phrasings(content):
    words = LEX.content(content)
    assert len(set(words.train)) >= 25
    assert words.heldout, "every content holds some phrasings out of training"
    for phrase in (*words.train, *words.heldout):
        assert marked_verbs(phrase), phrase  # at least one inflectable verb
        assert _sides(phrase) == _want_side(content), phrase


@pytest.mark.parametrize("style", sorted(set(D1_STYLES) | set(D2_STYLES)))
def test_every_style_has_10_phrasings(style):
    sw = LEX.style(style)
    assert sum(len(set(sw.kind(k).train)) for k in STYLE_KINDS) >= 10
    assert sum(len(sw.kind(k).heldout) for k in STYLE_KINDS) >= 1


def test_heldout_words_never_in_training_captions():
    assert len(LEX.heldout_words) >= 50
    for content, style in PAIRS:
        for seed in (0, "clip", 7):
            for text, _ in captions_for(content, style, n=16, seed=seed):
                assert not (_words(text) & LEX.heldout_words), text
    # and the held-out phrasings do use them
    for words in LEX.contents.values():
        for phrase in words.heldout:
            assert _words(phrase) & LEX.heldout_words, phrase
    text = " ".join(t for t, _ in captions_for("walk", "tired", n=8, seed=0, heldout=True))
    assert _words(text) & LEX.heldout_words


def test_examples_only_in_the_known_actions_never_in_training_captions():
    """A content's ``examples`` (a raised fist is a raise) widen the known-action check, mirrored like the rest, and
    never reach a training caption; like the training phrasings they avoid the held-out words."""
    from stablemofusion.data.lexicon import known_actions

    examples = {label: words.examples for label, words in LEX.contents.items() if words.examples}
    assert {"raise-up-left-hand", "raise-up-right-hand", "raise-up-both-hands"} <= set(examples)
    assert examples["raise-up-right-hand"] == tuple(map(LEX.mirror_text, examples["raise-up-left-hand"]))
    actions = known_actions(LEX, 0.5)["actions"]
    assert "a person raises their right fist in the air" in actions["raise-up-right-hand"]
    for label, phrases in examples.items():
        assert not any(_words(p) & LEX.heldout_words for p in phrases), label
        captions = {t for style in D2_STYLES for t, _ in captions_for(label, style, n=48, seed=0)}
        assert not any("fist" in c for c in captions), label


def test_at_least_30_structures_and_used():
    assert len(STRUCTURES) >= 30
    assert len(structures_for(LEX, "tired")) >= 30
    forms = {c.form for s in range(4) for c in generate("walk", "tired", n=16, seed=s)}
    assert len(forms) >= 25


def test_deterministic():
    a = captions_for("walk", "tired", seed="dataset-1_walk_tired_001")
    assert a == captions_for("walk", "tired", seed="dataset-1_walk_tired_001")
    assert a != captions_for("walk", "tired", seed="dataset-1_walk_tired_002")
    assert captions_for("kick", "normal", n=3, seed=3) == captions_for("kick", "normal", seed=3)[:3]


def test_count():
    assert captions_for("bow", "happy", n=0) == []
    assert len({c.lower() for c, _ in captions_for("walk", "normal", n=30, seed=1)}) == 30
    with pytest.raises(SMFError):
        captions_for("walk", "normal", n=-1)


@pytest.mark.parametrize("content,style", PAIRS)
def test_pair(content, style):
    caps = generate(content, style, n=12, seed="clip")
    texts = [c.text for c in caps]
    assert len({t.lower() for t in texts}) == 12
    assert len({c.form for c in caps}) >= 8
    for c in caps:
        assert "  " not in c.text and "{" not in c.text and "<" not in c.text, c.text
        assert not re.search(r"\ba [aeiou](?!ni|se|su|ne)|\ban [b-df-hj-np-tv-z]", c.text.lower()), c.text
        assert _sides(c.text) == _want_side(content), c.text
        words = re.findall(r"[A-Za-z][A-Za-z'-]*", c.text)
        assert len(c.tokens) == len(words), (c.text, c.tokens)
        for tok in c.tokens:
            word, pos = tok.rsplit("/", 1)
            assert pos in POS_TAGS and word == word.lower(), tok
    if style != "normal":  # the style is said in (almost) every caption
        said = sum(bool(_words(t) & _style_words(style)) for t in texts)
        assert said >= 10, texts


def test_normal_sometimes_omits_style():
    caps = [c for s in range(5) for c in generate("walk", "normal", n=12, seed=s)]
    plain = [c for c in caps if c.form.startswith("plain")]
    assert 0 < len(plain) < len(caps)


def test_tokens_lemmatise_verbs():
    caps = generate("raise-up-left-hand", "elderly", n=12, seed=0)
    verbs = [t for c in caps for t in c.tokens if t.endswith("/VERB")]
    assert verbs and all(not v.split("/")[0].endswith("ing") or v.split("/")[0] == "bring" for v in verbs), verbs


def test_verb_forms():
    assert verb_forms("walk") == ("walk", "walks", "walking")
    assert verb_forms("jog") == ("jog", "jogs", "jogging")
    assert verb_forms("wave") == ("wave", "waves", "waving")
    assert verb_forms("go|goes|going") == ("go", "goes", "going")
    with pytest.raises(SMFError):
        verb_forms("a|b")


def test_lexicon_same_as_and_mirror():
    lex = parse_lexicon({"mirror": {"left": "right", "right": "left"},
                         "contents": {"walk-left": {"train": ["<walk> to the left"]}, "dance": ["<dance>"]},
                         "styles": {"old": {"adjectives": ["old"]}, "elderly": {"same_as": "old"}}})
    assert lex.content("walk-right").train == ("<walk> to the right",)
    assert lex.style("elderly").adjectives.train == ("old",)
    with pytest.raises(SMFError, match="same_as"):
        parse_lexicon({"contents": {}, "styles": {"a": {"same_as": "b"}, "b": {"same_as": "a"}}})
    free = parse_lexicon({"mirror": {"left": "right", "right": "left"}, "contents": {"wave-left": ["<wave>"],
                                                                                    "run": ["<run>"]},
                          "styles": {}, "tempo_free": ["wave-left"]}).tempo_free
    assert free == {"wave-left", "wave-right"} and not lex.tempo_free
    with pytest.raises(SMFError, match="unknown content label 'jog'"):
        parse_lexicon({"contents": {"run": ["<run>"]}, "styles": {}, "tempo_free": ["jog"]})


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
            assert (mirror_caption(text) != text) == ("left" in content or "right" in content)


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
    for c in LEX.contents:
        assert mirror_label(mirror_label(c)) == c
        assert mirror_label(c) in LEX.contents
    assert mirror_label("wave-both-hands") == "wave-both-hands" and mirror_label("walk-back") == "walk-back"


def test_unknown_labels():
    with pytest.raises(SMFError, match=r"unknown content label 'jump'.*walk-back"):
        captions_for("jump", "normal")
    with pytest.raises(SMFError, match=r"unknown style label 'sleepyhead'.*chimpira"):
        captions_for("walk", "sleepyhead")
    with pytest.raises(SMFError, match="jump"):
        mirror_label("jump")


def test_paraphrases_say_a_caption_with_other_phrasings_of_its_move():
    """A plain running caption gets the running and sprinting phrasings of the lexicon (the contents it describes
    with "run") after its own subject and style words; a walk forward never becomes a walk backwards or a turn; a
    verb the lexicon does not use for any move, or a caption without a subject, gives none."""
    assert described_by("an active person runs forward") == ["run", "dash"]
    said = paraphrases("an active person runs forward", 8, seed="clip-1")
    assert len(said) == len(set(said)) == 8 and "an active person runs forward" not in said
    assert all(p.startswith("an active person ") for p in said)
    words = " ".join(paraphrases("an active person runs forward", 60, seed=0)).lower()
    assert all(w in words for w in ("jogs", "sprints", "dashes", "races"))
    assert paraphrases("an active person runs forward", 8, seed="clip-1") == said  # deterministic
    assert paraphrases("an active person runs forward", 8, seed="clip-2") != said
    walks = paraphrases("a man walks forward", 40, seed=0)
    assert walks and not re.search(r"\b(back|backwards?|left|right|turns?|around)\b", " ".join(walks).lower())
    assert paraphrases("a woman walks forward", 40, seed=0)[0].startswith("a woman ")
    assert paraphrases("a person hops on one leg", 8) == [] and paraphrases("run forward", 8) == []
    assert paraphrases("a person runs", 0) == []
