"""The motion classifier and the prompt-following metric: known answers on real clips, files, CLI errors."""

import json
from dataclasses import dataclass

import numpy as np
import pytest

from stablemofusion.cli.main import main
from stablemofusion.data.dataset import MotionTextDataset
from stablemofusion.eval.classifier import (
                                            corpus_labels,
                                            dataset_labels,
                                            label_accuracy,
                                            load_classifier,
                                            real_accuracy,
                                            )
from stablemofusion.eval.prompts import format_prompt_accuracy, load_prompts, prompt_accuracy


def test_label_accuracy_known_answers():
    pred = [("walk", "tired"), ("run", "happy"), ("bow", "old"), ("walk", "old")]
    want = [(("walk",), ("tired",)), (("walk", "run"), ()), (("kick",), ("old", "elderly")), (("walk",), ("sad",))]
    acc = label_accuracy(pred, want)
    assert acc == {"content_acc": 0.75, "style_acc": 2 / 3, "n": 4, "n_style": 3}


def test_corpus_labels_include_mirrors(eval_corpus):
    labels = corpus_labels(eval_corpus)
    left = [k for k, v in labels.items() if v.content == "walk-turn-left"]
    assert left and all(labels[("M" + k) if not k.startswith("M") else k[1:]].content == "walk-turn-right"
                        for k in left)
    assert dataset_labels(labels, 2) == (("walk-turn-left", "walk-turn-right", "wave-left-hand", "wave-right-hand"),
                                         ("active", "normal"))


def test_classifier_learns_the_clips_and_round_trips(classifier_dir, eval_corpus):
    model = load_classifier(classifier_dir)
    labels = corpus_labels(eval_corpus)
    acc = real_accuracy(model, eval_corpus, "test", labels)  # the mini corpus's test split = its train split
    assert acc["dataset-1"]["content_acc"] >= 0.8 and acc["dataset-2"]["content_acc"] >= 0.8
    saved = json.loads((classifier_dir / "classifier.json").read_text())
    assert saved["accuracy"]["test"] == acc  # the same weights give the same answers after loading
    # choosing among a dataset's labels only: a dataset-2 motion can only get a dataset-2 label
    ds = MotionTextDataset(eval_corpus, "test", feat_bias=1.0)
    feats = [ds.denormalize(m) for m in ds.motions]
    pred = model.predict(feats, [dataset_labels(labels, 2)] * len(feats))
    assert {p[0] for p in pred} <= set(dataset_labels(labels, 2)[0])


@dataclass
class _Result:
    features: np.ndarray


class _Replay:
    """A stand-in generator that returns a real clip for each prompt (so the right answer is known)."""

    def __init__(self, table):
        self.table, self.calls = table, []

    def __call__(self, prompts, seconds, seed, **sampling):
        self.calls.append((list(prompts), seconds, list(seed), sampling))
        return [_Result(self.table[p]) for p in prompts]


def test_prompt_accuracy_counts_what_the_classifier_sees(classifier_dir, eval_corpus, tmp_path):
    model = load_classifier(classifier_dir)
    labels = corpus_labels(eval_corpus)
    ds = MotionTextDataset(eval_corpus, "test", feat_bias=1.0)
    by_content = {}
    for mid, m in zip(ds.ids, ds.motions):
        by_content.setdefault(labels[mid].content, ds.denormalize(m))
    lines = [{"prompt": "stroll ahead", "content": "walk", "style": "normal", "dataset": 1},
             {"prompt": "jog", "content": ["run", "walk"], "style": None, "dataset": 1},
             {"prompt": "wave your left hand", "content": "wave-left-hand", "style": "active", "dataset": 2},
             {"prompt": "wrong on purpose", "content": "walk-turn-left", "style": "normal", "dataset": 2},
             {"prompt": "does a backflip", "content": None, "style": None, "dataset": None, "ood": True}]
    path = tmp_path / "p.jsonl"
    path.write_text("".join(json.dumps(d) + "\n" for d in lines))
    items = load_prompts(path)
    table = {"stroll ahead": by_content["walk"], "jog": by_content["walk"],
             "wave your left hand": by_content["wave-left-hand"], "wrong on purpose": by_content["wave-left-hand"]}
    gen = _Replay(table)
    res = prompt_accuracy(gen, model, items, labels, samples=2, seconds=3.0, seed=4, guidance_scale=4.0, steps=2)
    assert gen.calls[0][1] == 3.0 and gen.calls[0][2] == [4, 5, 4, 5, 4, 5, 4, 5]  # the OOD line is not generated
    assert gen.calls[0][3] == {"guidance_scale": 4.0, "steps": 2}  # the sampling settings reach the pipeline
    pred = model.predict([table[it.prompt] for it in items[:4] for _ in range(2)],
                         [dataset_labels(labels, it.dataset) for it in items[:4] for _ in range(2)])
    want = [(it.contents, it.styles) for it in items[:4] for _ in range(2)]
    assert res["all"] == label_accuracy(pred, want)
    assert res["dataset-2"]["content_acc"] <= 0.5  # the deliberately wrong prompt is counted wrong
    assert "dataset-1" in format_prompt_accuracy(res)


@pytest.mark.parametrize("line,msg", [
    ("{not json", "p.jsonl:1: not valid JSON"),
    ('{"content": "walk"}', "p.jsonl:1: needs a non-empty string 'prompt'"),
    ('{"prompt": "walk", "content": 3}', "p.jsonl:1: a label must be"),
    ('{"prompt": "walk"}', "p.jsonl:1: an in-domain prompt needs a 'content' label"),
])
def test_bad_prompt_files(tmp_path, line, msg):
    from stablemofusion.core.errors import SMFError

    (tmp_path / "p.jsonl").write_text(line + "\n")
    with pytest.raises(SMFError, match=msg):
        load_prompts(tmp_path / "p.jsonl")


def test_evaluate_prompts_cli(classifier_dir, eval_corpus, tiny_checkpoint, tmp_path, capsys, monkeypatch):
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    calls, call = [], MotionPipeline.__call__
    monkeypatch.setattr(MotionPipeline, "__call__", lambda self, *a, **kw: calls.append(kw) or call(self, *a, **kw))
    path = tmp_path / "p.jsonl"
    path.write_text(json.dumps({"prompt": "a man walks", "content": "walk", "style": None, "dataset": 1}) + "\n")
    out = tmp_path / "r.json"
    code = main(["evaluate", "--checkpoint", str(tiny_checkpoint), "--data", str(eval_corpus), "--classifier",
                 str(classifier_dir), "--prompts", str(path), "--prompts-only", "--prompt-samples", "2",
                 "--steps", "2", "--out", str(out)])
    assert code == 0
    full = json.loads(out.read_text())
    res = full["prompts"]
    assert res["all"]["n"] == 2 and "Prompt following" in capsys.readouterr().out
    assert full["sampling"] == {"guidance_scale": 2.5, "steps": 2, "sampler": "sde-dpmsolver++-karras", "footskate": "off"}
    assert calls and all(kw["steps"] == 2 and kw["guidance_scale"] == 2.5 for kw in calls)  # --steps is used; the model's guidance
    code = main(["evaluate", "--checkpoint", str(tiny_checkpoint), "--data", str(eval_corpus), "--classifier",
                 str(classifier_dir), "--prompts", str(path), "--prompts-only", "--prompt-samples", "1",
                 "--prompt-seconds", "auto", "--steps", "2", "--out", str(out)])
    assert code == 0 and json.loads(out.read_text())["prompts"]["seconds"] is None  # the pipeline's own length
    capsys.readouterr()
    for bad in ("abc", "0"):
        assert main(["evaluate", "--checkpoint", str(tiny_checkpoint), "--data", str(eval_corpus), "--classifier",
                     str(classifier_dir), "--prompts", str(path), "--prompts-only", "--prompt-seconds", bad]) == 2
        assert "--prompt-seconds positive or auto" in capsys.readouterr().err
    path.write_text(json.dumps({"prompt": "a man walks", "content": "jump", "dataset": 1}) + "\n")
    code = main(["evaluate", "--checkpoint", str(tiny_checkpoint), "--data", str(eval_corpus), "--classifier",
                 str(classifier_dir), "--prompts", str(path), "--prompts-only"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and "content 'jump' is unknown to the classifier" in err


def test_train_classifier_cli_errors(tmp_path, capsys):
    assert main(["train-classifier", "--data", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    assert "no such corpus folder" in capsys.readouterr().err
