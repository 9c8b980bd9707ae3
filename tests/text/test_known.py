"""The out-of-domain check: similarity to the actions a model knows, the detector (stablemofusion.text.domain),
the one-line warning, and where it shows up (pipeline result, `smf generate` output and JSON)."""

import json
import shutil
import warnings

import numpy as np
import pytest
import torch

from stablemofusion.cli.main import main
from stablemofusion.data.lexicon import known_actions, load_lexicon
from stablemofusion.core.errors import SMFError
from stablemofusion.pipelines.motion_pipeline import MotionPipeline, OutOfDomainWarning
from stablemofusion.text.cache import LRUTextCache
from stablemofusion.text.frozen import load_text_encoder
from stablemofusion.text.domain import DETECTOR_FILE, DomainDetector, train_classifier
from stablemofusion.text.known import ACTIONS_FILE, KnownActions
from stablemofusion.pipelines.motion_pipeline import default_model_path

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
    said = capsys.readouterr()
    assert code == 0 and "smf: warning:" not in said.out  # warnings on stderr, the results alone on stdout
    lines = [line for line in said.err.splitlines() if line.startswith("smf: warning:")]
    assert len(lines) == 1 and "closest actions it knows" in lines[0]
    (json_file,) = tmp_path.glob("*.json")
    d = json.loads(json_file.read_text())
    assert d["out_of_domain"] is True and 0 < d["similarity"] < THRESHOLD and len(d["closest_actions"]) == 3


def test_export_writes_actions_and_detector(checkpoint_with_actions, tmp_path, monkeypatch, cache):
    import stablemofusion.text.domain as domain

    # a small detector: few foreign and held-out captions, one epoch, a two-clip corpus
    monkeypatch.setattr(domain, "FOREIGN_PER_PHRASE", 1)
    monkeypatch.setattr(domain, "HELDOUT_PER_PAIR", 1)
    monkeypatch.setattr(domain, "EPOCHS", 1)
    corpus = tmp_path / "corpus"
    (corpus / "texts").mkdir(parents=True)
    (corpus / "train.txt").write_text("000000\n000001\n")
    (corpus / "texts" / "000000.txt").write_text("a man walks forward#a/DET man/NOUN#0.0#0.0\n"
                                                "a person strolls ahead#a/DET#0.0#0.0\n")
    (corpus / "texts" / "000001.txt").write_text("someone waves both hands#someone/PRON#0.0#0.0\n")
    assert main(["export", "--checkpoint", str(checkpoint_with_actions), "--out", str(tmp_path / "rel"),
                 "--lexicon", "bandai", "--corpus", str(corpus)]) == 0
    d = json.loads((tmp_path / "rel" / ACTIONS_FILE).read_text())
    assert d["threshold"] == DomainDetector.THRESHOLD and len(d["actions"]["walk"]) >= 25
    assert {"run", "bow"} <= set(d["actions"])  # an unlabelled corpus: every action of the lexicon
    # a labelled corpus (clips.csv): the model knows the lexicon's actions that its clips hold, no others
    (corpus / "clips.csv").write_text("id,clip,dataset,content,style\n000000,a,1,walk,normal\n"
                                      "000001,b,2,wave-both-hands,happy\n")
    assert main(["export", "--checkpoint", str(checkpoint_with_actions), "--out", str(tmp_path / "labelled"),
                 "--lexicon", "bandai", "--corpus", str(corpus)]) == 0
    assert set(json.loads((tmp_path / "labelled" / ACTIONS_FILE).read_text())["actions"]) == {"walk", "wave-both-hands"}
    assert d["detector"]["file"] == DETECTOR_FILE and (tmp_path / "rel" / DETECTOR_FILE).is_file()
    known = KnownActions.load(tmp_path / "rel" / ACTIONS_FILE, cache, DomainDetector.load)
    assert known.detector is not None and 0 < known.check("a person walks forward").similarity < 1


# ------------------------------------------------------------------------------- the detector (ood.safetensors)

def test_detector_save_load_round_trip(tmp_path):
    g = torch.Generator().manual_seed(0)
    inside = torch.nn.functional.normalize(torch.randn(64, 384, generator=g) + 2, dim=1)
    outside = torch.nn.functional.normalize(torch.randn(64, 384, generator=g) - 2, dim=1)
    det = DomainDetector.calibrate(train_classifier(inside, outside, epochs=3), inside, 0.05)
    s = det.scores(torch.cat([inside, outside]))
    assert (s[:64] > 0.5).float().mean() >= 0.9 and (s[64:] < 0.5).all()  # the two clouds apart
    det.save(tmp_path / DETECTOR_FILE)
    back = DomainDetector.load(tmp_path / DETECTOR_FILE)
    assert back.offset == det.offset and back.scale == det.scale and back.encoder == "minilm"
    assert torch.allclose(back.scores(torch.cat([inside, outside])), s, atol=2e-3)  # float16 weights
    known = KnownActions({"walk": ["a person walks"]}, 0.5, None, detector=det)
    known.save(tmp_path)
    assert json.loads((tmp_path / ACTIONS_FILE).read_text())["detector"] == {"file": DETECTOR_FILE}


def test_bad_detector_files(tmp_path, cache):
    (tmp_path / DETECTOR_FILE).write_bytes(b"not safetensors")
    with pytest.raises(SMFError, match="not an out-of-domain detector"):
        DomainDetector.load(tmp_path / DETECTOR_FILE)
    (tmp_path / ACTIONS_FILE).write_text(json.dumps({"actions": {"walk": ["a person walks"]}, "threshold": 0.5,
                                                     "detector": {"file": "../elsewhere.safetensors"}}))
    with pytest.raises(SMFError, match="beside it"):
        KnownActions.load(tmp_path / ACTIONS_FILE, cache)


@pytest.fixture(scope="module")
def shipped(cache):
    """The default model's actions.json with its detector."""
    path = default_model_path() / ACTIONS_FILE
    known = KnownActions.load(path, cache, DomainDetector.load)
    assert known.detector is not None
    return known


FOREIGN = ("a man plays the saxophone on a street corner", "a woman rides a camel across the desert",
           "a boy does a backflip off the diving board", "a person knits a sweater on the sofa")
# in-domain paraphrases built from the lexicon's held-out words (never seen in training), long and styled
PARAPHRASES = ("an old man ambles straight ahead", "a tired woman saunters forward at an easy pace",
               "she lopes forward like a sprinter", "a man in a red jacket raises both arms heavenward",
               "a happy child bids adieu with one hand")


def test_shipped_detector_known_answers(shipped):
    for prompt in FOREIGN:
        d = shipped.check(prompt)
        assert d.out_of_domain and d.similarity < 0.5, (prompt, d)
    for prompt in PARAPHRASES:
        d = shipped.check(prompt)
        assert not d.out_of_domain and d.similarity >= 0.5, (prompt, d)


def test_shipped_detector_file_is_small():
    folder = default_model_path()
    assert (folder / DETECTOR_FILE).stat().st_size < 400_000 and (folder / ACTIONS_FILE).stat().st_size < 100_000


@pytest.fixture(scope="module")
def checkpoint_with_detector(tmp_path_factory, save_tiny_checkpoint):
    path = save_tiny_checkpoint(tmp_path_factory.mktemp("ood-det") / "ck", np.zeros(263), np.ones(263))
    for name in (ACTIONS_FILE, DETECTOR_FILE):
        shutil.copy(default_model_path() / name, path / name)
    return path


def test_detector_warning_and_fields_keep_their_shape(checkpoint_with_detector, checkpoint_with_actions, tmp_path,
                                                      capsys):
    """The CLI warning line and the JSON fields are the same with the detector as with the old actions file."""
    fields = {}
    for name, ck in (("detector", checkpoint_with_detector), ("old", checkpoint_with_actions)):
        out = tmp_path / name
        assert main(["generate", FOREIGN[0], "--checkpoint", str(ck), "--seconds", "2", "--steps", "2",
                     "--format", "json", "--out", str(out)]) == 0
        lines = [x for x in capsys.readouterr().err.splitlines() if x.startswith("smf: warning:")]
        assert len(lines) == 1 and "is not like anything this model was trained on" in lines[0]
        assert "closest actions it knows" in lines[0]
        (json_file,) = out.glob("*.json")
        d = json.loads(json_file.read_text())
        fields[name] = {k: type(d[k]) for k in ("similarity", "out_of_domain", "closest_actions", "warning")}
        assert d["out_of_domain"] is True and 0 <= d["similarity"] < 1 and len(d["closest_actions"]) == 3
    assert fields["detector"] == fields["old"]
    pipe = MotionPipeline.from_pretrained(checkpoint_with_detector, device="cpu")
    assert pipe.known_actions.detector is not None
    d = pipe.known_actions.check("a person walks forward")
    assert not d.out_of_domain and d.closest[0][0] == "walk"
    assert set(d.to_dict("a person walks forward")) == {"similarity", "out_of_domain", "closest_actions"}


def test_shipped_detector_on_held_out_foreign_prompts_and_its_calibration(shipped):
    """The threshold flags about FLAG_RATE of its calibration prompts and >= 90% of the held-out foreign prompts
    (benchmarks/ood_heldout.txt, never used to train or calibrate it)."""
    from pathlib import Path

    from stablemofusion.text.domain import FLAG_RATE, calibration_inside

    calib = calibration_inside("bandai")
    assert len(calib) >= 100 and not any(x.startswith("#") for x in calib)
    flagged = np.mean([c.out_of_domain for c in shipped.check_many(calib)])
    assert flagged <= FLAG_RATE + 0.02
    text = (Path(__file__).parents[2] / "benchmarks" / "ood_heldout.txt").read_text()
    foreign = [x.strip() for x in text.splitlines() if x.strip() and not x.startswith("#")]
    assert np.mean([c.out_of_domain for c in shipped.check_many(foreign)]) >= 0.9


def test_foreign_phrasings_are_a_data_file_and_fill_the_grammar():
    from stablemofusion.text.foreign import foreign_captions, foreign_phrases

    phrases = foreign_phrases()
    assert len(phrases) >= 400 and len(set(phrases)) == len(phrases)
    captions = foreign_captions(2)
    assert len(captions) == 2 * len(phrases)
    assert not any("<" in c or "{" in c for c in captions)  # every verb form and slot filled


def test_example_embeddings_are_read_from_the_model_folder_when_they_match(tmp_path, cache):
    """A process's first check reads the stored embeddings instead of encoding every example (the shipped
    model's once, in its graphs' actions.npy; another folder's actions.safetensors); a stale file (other
    sentences) is ignored, and the stored embeddings equal freshly encoded ones."""
    from stablemofusion.text.known import EMBEDDINGS_FILE

    folder = default_model_path()
    assert not (folder / EMBEDDINGS_FILE).exists() and (folder / "onnx" / "actions.npy").is_file()
    known = KnownActions.load(folder / ACTIONS_FILE, cache)
    assert known._emb is not None  # read, not encoded
    fresh = KnownActions(known.actions, known.threshold, LRUTextCache(load_text_encoder("minilm")))
    assert np.allclose(known._emb, fresh.examples_embedding(), atol=1e-5)

    small = KnownActions({"walk": ["a person walks"], "bow": ["a person bows"]}, 0.5, cache)
    small.save(tmp_path)
    assert KnownActions.load(tmp_path / ACTIONS_FILE, cache)._emb is not None
    d = json.loads((tmp_path / ACTIONS_FILE).read_text())
    d["actions"]["bow"] = ["a person bows deeply"]
    (tmp_path / ACTIONS_FILE).write_text(json.dumps(d))
    stale = KnownActions.load(tmp_path / ACTIONS_FILE, cache)
    assert stale._emb is None and stale.check("a person bows deeply").closest[0] == ("bow", pytest.approx(1.0, abs=1e-5))
    (tmp_path / EMBEDDINGS_FILE).write_bytes(b"not safetensors")
    assert KnownActions.load(tmp_path / ACTIONS_FILE, cache)._emb is None


def test_the_warning_names_one_figure_the_one_the_decision_used():
    """'a boxer throws punches' was flagged at 0.49 while the line also said 'punch (0.91)': one figure now."""
    import re

    from stablemofusion.text.known import DomainCheck

    check = DomainCheck(0.49, (("punch", 0.91), ("kick", 0.8)), True)
    message = check.message("a boxer throws punches")
    assert re.findall(r"\d+\.\d+", message) == ["0.49"] and "in-domain score 0.49" in message
    assert "punch, kick" in message and check.to_dict("x")["warning"] == message.replace("a boxer throws punches", "x")


def test_a_prompt_clearly_closest_to_a_taught_action_is_answered_with_its_nearest_clip_caption(bandai):
    """An adapter's captions (its clips' and their paraphrases): a paraphrase clearly closest to its action is
    answered with the nearest clip caption, never a paraphrase; a prompt of another action, or one the margin does
    not separate, keeps its own words; without the clips' captions nothing is answered."""
    from stablemofusion.text.known import TAUGHT_MARGIN

    clips = ["an elderly person hops on one leg", "a person hops on one leg"]
    taught = {"hop": clips + ["a person bounces on one foot", "an old person springs on one foot"]}
    known = bandai.with_taught([taught], [clips + ["a person waves"]])
    assert known.taught_clips == {"hop": clips}
    d = known.check("an old man bounces on one foot")
    assert d.closest[0][0] == "hop" and d.closest[0][1] - d.closest[1][1] >= TAUGHT_MARGIN
    assert d.answer == "an elderly person hops on one leg"
    assert d.to_dict("x")["answered_as"] == d.answer and d.answer in d.answer_message("x")
    for prompt in ("a person waves with the right hand", "an old man walks slowly forward"):
        assert known.check(prompt).answer is None, prompt
    assert bandai.with_taught([taught]).check("an old man bounces on one foot").answer is None
    assert bandai.check("an old man bounces on one foot").answer is None
