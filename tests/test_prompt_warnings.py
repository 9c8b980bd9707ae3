"""Prompts that are not English are told apart: the ten written before the check and ten more written after it
(five languages or more, three scripts), and none of the English prompt sets; the result carries the warning."""

import json
from pathlib import Path

import pytest

from stablemofusion.core.language import not_english
from stablemofusion.core.output import slug

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _prompts(name: str) -> list[str]:
    return [json.loads(line)["prompt"] for line in (BENCH / name).read_text(encoding="utf-8").splitlines() if line]


@pytest.mark.parametrize("name", ["prompts_foreign.jsonl", "prompts_foreign_heldout.jsonl"])
def test_every_prompt_in_another_language_or_script_is_told(name):
    assert [p for p in _prompts(name) if not_english(p) is None] == []


def test_no_english_prompt_is_taken_for_another_language():
    english = [p for name in ("prompts_freeform.jsonl", "prompts_plain.jsonl", "prompts_heldout_lexicon.jsonl",
                              "prompts_sequences.jsonl") for p in _prompts(name)]
    assert len(english) > 600 and [p for p in english if not_english(p)] == []


def test_why_is_named():
    assert not_english("человек идёт") == "Cyrillic script"
    assert not_english("一个人向前走") == "Chinese, Japanese or Korean script"
    assert not_english("🕺💃") == "no words"
    assert not_english("ein Mann geht langsam nach vorne") == "German words"
    assert not_english("a person dances 🕺") is None


def test_file_names_keep_any_script_and_end_at_a_word():
    assert slug("一个人向前走", 1) == "001_一个人向前走"
    assert slug("a person walks forward and turns left 90 degrees then waves", 0) == \
        "000_a_person_walks_forward_and_turns_left_90_degrees"
    assert slug("🕺", 2) == "002_motion"


def test_the_result_and_the_answer_carry_the_warning():
    from stablemofusion.core.final import NotEnglishWarning
    from stablemofusion.core.output import json_payload
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    with pytest.warns(NotEnglishWarning, match="French words"):
        r = pipe("une personne marche lentement vers l'avant", seconds=2, seed=0)[0]
    assert "does not look like English (French words)" in json_payload(r)["warnings"][0]
    assert pipe("a person walks forward", seconds=2, seed=0)[0].warnings == []


def test_prompts_of_actions_the_model_draws_badly_are_warned_with_why():
    """The shipped model's reliability table (benchmarks/action_reliability.py) marks kick, punch and slash weak
    (2-4 clips each); their prompts are warned, with the clips and the measured accuracy, well-drawn ones are not."""
    from stablemofusion.core.final import WeakActionWarning
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    assert {a for a, r in pipe.backend.reliability.items() if r.weak} >= {"kick", "punch", "slash"}
    for prompt, action in [("a person kicks with the right leg", "kick"), ("a man punches the air", "punch"),
                           ("someone slashes with a sword", "slash")]:
        with pytest.warns(WeakActionWarning, match=f"closest to '{action}', which this model draws badly"):
            r = pipe(prompt, seconds=2, seed=0)[0]
        assert any("draws badly (it was taught by" in w for w in r.warnings)
    assert not any("draws badly" in w for w in pipe(["a person walks forward", "a person waves both hands"],
                                                   seconds=2, seed=0)[0].warnings)


@pytest.mark.parametrize("prompt", ["a tough, manly soldier thrusts his right fist high overhead",
                                    "a confident model struts down the runway"])
def test_prompts_of_actions_drawn_well_are_not_taken_for_weak_ones(prompt):
    """A fist raised overhead is a raise (the lexicon's examples), not a punch; a prompt no known action is close to
    (every one under WEAK_FLOOR) names none: neither is warned as an action the model draws badly."""
    from stablemofusion.core.reliability import WEAK_FLOOR, weak_action
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    domain = pipe.backend.domains([prompt])[0]
    assert weak_action(domain, pipe.backend.reliability) is None
    assert domain.closest[0][0] == "raise-up-right-hand" or domain.closest[0][1] < WEAK_FLOOR
    assert not any("draws badly" in w for w in pipe(prompt, seconds=2, seed=0)[0].warnings)
