"""The out-of-domain check: similarity to the actions a model knows, the one-line warning, and where it
shows up (pipeline result, `smf generate` output and JSON)."""

import json
import warnings

import numpy as np
import pytest

from stablemofusion.cli.main import main
from stablemofusion.data.lexicon import known_actions, load_lexicon
from stablemofusion.errors import SMFError
from stablemofusion.pipeline import MotionPipeline, OutOfDomainWarning
from stablemofusion.text.cache import LRUTextCache
from stablemofusion.text.frozen import load_text_encoder
from stablemofusion.text.known import ACTIONS_FILE, KnownActions

THRESHOLD = 0.56  # smf export's default


@pytest.fixture(scope="module")
def cache():
    return LRUTextCache(load_text_encoder("minilm"), maxsize=10_000)


@pytest.fixture(scope="module")
def bandai(cache):
    return KnownActions(known_actions(load_lexicon("bandai"), THRESHOLD)["actions"], THRESHOLD, cache)


def test_an_example_sentence_is_its_own_closest_action(cache):
    known = KnownActions({"walk": ["a person walks forward"], "bow": ["a person bows"]}, 0.5, cache)
    d = known.check("a person walks forward")
    assert d.closest[0][0] == "walk" and d.similarity == pytest.approx(1.0, abs=1e-5) and not d.out_of_domain
    assert [label for label, _ in d.closest] == ["walk", "bow"]


def test_corpus_actions_and_out_of_domain_prompts(bandai):
    inside = bandai.check_many(["an old man walks slowly forward", "waves both hands happily", "takes a bow"])
    for d, label in zip(inside, ("walk", "wave-both-hands", "bow")):
        assert label in [c for c, _ in d.closest], d
    assert not any(d.out_of_domain for d in inside)
    for prompt in ("does a backflip", "swims freestyle in a pool", "plays the piano"):
        d = bandai.check(prompt)
        assert d.out_of_domain, (prompt, d)
        msg = d.message(prompt)
        assert "\n" not in msg and prompt in msg and d.closest[0][0] in msg and f"{d.similarity:.2f}" in msg


def test_bad_actions_file(tmp_path, cache):
    (tmp_path / ACTIONS_FILE).write_text('{"actions": {"walk": []}, "threshold": 0.5}')
    with pytest.raises(SMFError, match="at least one example"):
        KnownActions.load(tmp_path / ACTIONS_FILE, cache)
    (tmp_path / ACTIONS_FILE).write_text('{"threshold": 0.5}')
    with pytest.raises(SMFError, match="not an actions file"):
        KnownActions.load(tmp_path / ACTIONS_FILE, cache)


@pytest.fixture(scope="module")
def checkpoint_with_actions(tmp_path_factory, save_tiny_checkpoint):
    path = save_tiny_checkpoint(tmp_path_factory.mktemp("ood") / "ck", np.zeros(263), np.ones(263))
    (path / ACTIONS_FILE).write_text(json.dumps(known_actions(load_lexicon("bandai"), THRESHOLD)))
    return path


def test_pipeline_warns_and_still_generates(checkpoint_with_actions):
    pipe = MotionPipeline.from_pretrained(checkpoint_with_actions, device="cpu")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        a, b = pipe(["does a backflip", "a person walks forward"], seconds=2, steps=2, seed=0)
    ood = [w for w in caught if issubclass(w.category, OutOfDomainWarning)]
    assert len(ood) == 1 and "does a backflip" in str(ood[0].message)
    assert a.domain.out_of_domain and not b.domain.out_of_domain and len(a.joints) == 40
    assert b.domain.closest[0][0] == "walk"


def test_generate_cli_prints_one_warning_line_and_writes_similarity(checkpoint_with_actions, tmp_path, capsys):
    code = main(["generate", "does a backflip", "--checkpoint", str(checkpoint_with_actions), "--seconds", "2",
                 "--steps", "2", "--format", "json", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert code == 0
    lines = [line for line in out.splitlines() if line.startswith("smf: warning:")]
    assert len(lines) == 1 and "closest actions it knows" in lines[0]
    (json_file,) = tmp_path.glob("*.json")
    d = json.loads(json_file.read_text())
    assert d["out_of_domain"] is True and 0 < d["similarity"] < THRESHOLD and len(d["closest_actions"]) == 3


def test_export_writes_actions(checkpoint_with_actions, tmp_path):
    assert main(["export", "--checkpoint", str(checkpoint_with_actions), "--out", str(tmp_path / "rel"),
                 "--lexicon", "bandai"]) == 0
    d = json.loads((tmp_path / "rel" / ACTIONS_FILE).read_text())
    assert d["threshold"] == THRESHOLD and len(d["actions"]["walk"]) >= 25
