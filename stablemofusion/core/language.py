"""Prompts that are not English, told apart without a model: the model's text encoder and its captions are English,
so a prompt in another language or script gets a motion unrelated to it. A prompt is taken for another language
when it holds letters of another script than the Latin one, holds no letters at all, or holds more of another
language's common words than of English's (at least two), or some of them and no English one in three words or
more (the word lists are data, ``assets/lexicons/languages.json``)."""

from __future__ import annotations

import json
import re
import unicodedata
from functools import lru_cache
from importlib import resources


MIN_WORDS = 2  # another language's words that outnumber English's, at least this many
MIN_WORDS_ALONE = 3  # or one of them and no English word, in a prompt of at least this many words


@lru_cache(maxsize=1)
def _lexicon() -> dict:
    text = (resources.files("stablemofusion") / "assets" / "lexicons" / "languages.json").read_text("utf-8")
    data = json.loads(text)
    return {"names": data["names"], "words": {k: frozenset(v) for k, v in data["words"].items()}}


def language_lexicon() -> dict:
    """The word lists as data (names, words by language, and the rule's numbers), for the JavaScript runtime."""
    lex = _lexicon()
    return {"names": lex["names"], "words": {k: sorted(v) for k, v in lex["words"].items()},
            "min_words": MIN_WORDS, "min_words_alone": MIN_WORDS_ALONE}


def _script(ch: str) -> str:
    """The script of a letter, from its Unicode name ('LATIN', 'CJK', 'CYRILLIC', ...)."""
    name = unicodedata.name(ch, "")
    return "CJK" if name.startswith(("CJK", "HIRAGANA", "KATAKANA", "HANGUL")) else name.split(" ")[0]


def not_english(prompt: str) -> str | None:
    """Why ``prompt`` is not English (a short phrase: 'Cyrillic script', 'French words', 'no words'), or None."""
    letters = [c for c in prompt if c.isalpha()]
    if not letters:
        return "no words"
    scripts = {_script(c) for c in letters} - {"LATIN"}
    if scripts:
        script = sorted(scripts)[0]
        return "Chinese, Japanese or Korean script" if script == "CJK" else f"{script.title()} script"
    lex = _lexicon()
    words = re.findall(r"[^\W\d_]+", prompt.lower())
    english = sum(w in lex["words"]["en"] for w in words)
    best, language = max((sum(w in ws for w in words), code) for code, ws in lex["words"].items() if code != "en")
    if (best >= MIN_WORDS and best > english) or (best >= 1 and english == 0 and len(words) >= MIN_WORDS_ALONE):
        return f"{lex['names'][language]} words"
    return None


def language_message(prompt: str, why: str) -> str:
    """One warning line for a prompt that is not English."""
    return (f"{prompt!r} does not look like English ({why}): the model knows English prompts only, so the motion may "
            "not follow it")


__all__ = ["MIN_WORDS", "MIN_WORDS_ALONE", "language_lexicon", "language_message", "not_english"]
