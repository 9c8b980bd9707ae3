"""The T2M protocol end to end (tiny denoiser, small evaluator, real clips), ablation tables and CLIs."""

import json

import pytest
import torch

from stablemofusion.cli.main import main
from stablemofusion.eval.ablation import min_steps_within
from stablemofusion.eval.protocol import EmbeddingModel, EvalConfig, draw_items, evaluate, markdown_table
from stablemofusion.data.dataset import MotionTextDataset
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.text.cache import TextEmbeddingCache

CFG = dict(replications=2, batch_size=4, diversity_times=5, mm_captions=2, mm_repeats=4, mm_times=2, steps=2,
           gen_batch=8)


@pytest.fixture(scope="module")
def setup(tiny_checkpoint, evaluator_dir, eval_text_cache):
    from stablemofusion.eval.evaluator import load_evaluator

    torch.set_num_threads(1)
    pipe = MotionPipeline.from_pretrained(tiny_checkpoint, device="cpu")
    ev, _ = load_evaluator(evaluator_dir)
    return pipe, EmbeddingModel(ev, TextEmbeddingCache(eval_text_cache, "minilm"))


def test_test_items_are_cropped_to_multiples_of_4_and_reproducible(eval_corpus):
    ds = MotionTextDataset(eval_corpus, "test", seed=0, feat_bias=1.0)
    a, b = draw_items(ds, 3, 0, 4, None), draw_items(ds, 3, 0, 4, None)
    assert a.captions == b.captions and a.lengths == b.lengths
    assert len(a.captions) % 4 == 0 and all(n % 4 == 0 for n in a.lengths)
    assert all(len(r) == n for r, n in zip(a.real, a.lengths))
    assert draw_items(ds, 4, 0, 4, None).lengths != a.lengths or draw_items(ds, 4, 0, 4, None).captions != a.captions


def test_evaluate_rows_and_reproducibility(setup, eval_corpus):
    pipe, emb = setup
    cfg = EvalConfig(**CFG)
    res = evaluate(pipe, emb, eval_corpus, cfg, progress=False)
    real, gen = res["rows"]["Real motion"], res["rows"]["Generated"]
    assert len(res["runs"]["Generated"]) == 2 and res["aits_seconds"] > 0
    for row in (real, gen):
        assert row["top1"][0] <= row["top2"][0] <= row["top3"][0] <= 1
        assert row["fid"][0] >= 0 and row["diversity"][0] > 0
    assert "multimodality" in gen and "multimodality" not in real
    assert real["fid"][0] < gen["fid"][0]  # random weights are far from real motion; real crops are not
    again = evaluate(pipe, emb, eval_corpus, cfg, progress=False)
    assert again["rows"]["Generated"]["fid"] == pytest.approx(gen["fid"])
    table = markdown_table(res)
    assert "| Real motion |" in table and "| Generated |" in table and "MModality" in table


def test_min_steps_within_5_percent():
    def row(fid, top3):
        return {"fid": (fid, 0.0), "top3": (top3, 0.0)}

    by = {5: row(2.0, 0.50), 10: row(1.04, 0.70), 20: row(1.0, 0.72), 50: row(1.01, 0.73)}
    best = min_steps_within(by)
    assert best["steps"] == 10 and best["best_fid"] == 1.0 and best["best_top3"] == 0.73
    by[10] = row(1.2, 0.73)  # FID 20% off: the next count that fits both
    assert min_steps_within(by)["steps"] == 20


def test_cli_evaluate_and_ablate_samplers(tiny_checkpoint, evaluator_dir, eval_corpus, tmp_path, capsys):
    common = ["--data", str(eval_corpus), "--evaluator", str(evaluator_dir), "--replications", "1", "--no-progress"]
    out = tmp_path / "res.json"
    # 14 test items: batches of 32 are impossible -> a clear error, no output
    assert main(["evaluate", "--checkpoint", str(tiny_checkpoint), *common, "--out", str(out)]) == 2
    assert "fewer than one batch of 32" in capsys.readouterr().err and not out.exists()
    assert main(["evaluate", "--checkpoint", str(tiny_checkpoint), "--data", str(eval_corpus)]) == 2
    assert "--evaluator" in capsys.readouterr().err
    assert main(["ablate", "samplers", "--checkpoint", str(tiny_checkpoint), *common, "--samplers", "nope",
                 "--out", str(out)]) == 2
    assert "nope" in capsys.readouterr().err
    assert main(["ablate", "samplers", "--checkpoint", str(tiny_checkpoint), *common, "--grid", "1,x",
                 "--out", str(out)]) == 2


def test_cli_evaluate_writes_json_and_markdown(tiny_checkpoint, evaluator_dir, eval_corpus, tmp_path, capsys):
    out = tmp_path / "res.json"
    assert main(["evaluate", "--checkpoint", str(tiny_checkpoint), "--data", str(eval_corpus), "--evaluator",
                 str(evaluator_dir), "--replications", "1", "--mm-captions", "0", "--steps", "2", "--no-progress",
                 "--rprecision-batch", "4", "--diversity-times", "5", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert set(res["rows"]) == {"Real motion", "Generated"} and res["config"]["steps"] == 2
    md = out.with_suffix(".md").read_text()
    assert "AITS" in md and "| Generated |" in md
    assert "| Generated |" in capsys.readouterr().out


def test_cli_original_t2m_evaluator_errors_name_the_problem(tiny_checkpoint, eval_corpus, tmp_path, capsys):
    base = ["evaluate", "--checkpoint", str(tiny_checkpoint), "--data", str(eval_corpus)]
    assert main([*base, "--t2m-evaluator", str(tmp_path)]) == 2
    assert "--glove" in capsys.readouterr().err
    assert main([*base, "--t2m-evaluator", str(tmp_path), "--glove", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "finest.tar" in err and err.count("\n") == 1


def test_cli_ablate_arch_and_samplers_write_tables(evaluator_dir, tiny_checkpoint, eval_corpus, eval_text_cache,
                                                   tmp_path, capsys):
    small = ["--data", str(eval_corpus), "--evaluator", str(evaluator_dir), "--replications", "1", "--no-progress",
             "--rprecision-batch", "4", "--diversity-times", "5", "--steps", "2"]
    out = tmp_path / "arch.json"
    assert main(["ablate", "arch", *small, "--presets", "tiny", "--train-steps", "2", "--batch-size", "4",
                 "--runs", str(tmp_path / "runs"), "--text-cache", str(eval_text_cache), "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["table"]["tiny"]["steps"] == 2 and res["train"]["steps"] == 2
    assert "| tiny |" in out.with_suffix(".md").read_text()
    out = tmp_path / "samplers.json"
    assert main(["ablate", "samplers", "--checkpoint", str(tiny_checkpoint), *small, "--samplers", "ddim,ddpm",
                 "--grid", "1,2", "--ddpm-steps", "3", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert sorted(res["runs"]["ddpm"]) == ["1", "2", "3"] and sorted(res["runs"]["ddim"]) == ["1", "2"]
    assert res["table"]["ddim"]["steps"] in (1, 2)
    assert "| ddpm |" in out.with_suffix(".md").read_text()


def test_evaluate_with_footskate_cleanup_reports_skating_and_joint_change(setup, eval_corpus):
    from stablemofusion.cli.evaluate import skate_fn
    from stablemofusion.motion.skeleton import get_skeleton

    pipe, emb = setup
    cfg = EvalConfig(**{**CFG, "replications": 1, "mm_captions": 0, "footskate": "post"})
    res = evaluate(pipe, emb, eval_corpus, cfg, progress=False, skate_metrics=skate_fn(get_skeleton("humanml3d")),
                   body=True)
    gen, real = res["rows"]["Generated"], res["rows"]["Real motion"]
    for key in ("skate_ratio", "slide_speed", "penetration", "bone_std", "bone_worst", "bone_worst_max", "npy_bvh_max"):
        assert key in gen and key in real
    assert gen["joint_change"][0] > 0 and gen["pose_change"][0] <= gen["joint_change"][0] + 1e-9
    assert gen["model_change"][0] >= gen["joint_change"][0] * 0.5
    assert gen["bone_worst_max"][0] < 1e-4 and gen["npy_bvh_max"][0] < 1e-3  # one rigid body in every output
    assert real["bone_worst_max"][0] < 1e-4
    assert real["skate_ratio"][0] < 0.3  # real motion capture barely skates


def test_cli_evaluate_defaults_to_the_shipped_model_and_none_means_real_only(evaluator_dir, eval_corpus, tmp_path):
    small = ["--data", str(eval_corpus), "--evaluator", str(evaluator_dir), "--replications", "1", "--no-progress",
             "--rprecision-batch", "4", "--diversity-times", "5", "--steps", "2", "--mm-captions", "0"]
    out = tmp_path / "default.json"
    assert main(["evaluate", *small, "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["checkpoint"] == "the shipped default model" and "Generated" in res["rows"]
    out = tmp_path / "real.json"
    assert main(["evaluate", "--checkpoint", "none", *small, "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert list(res["rows"]) == ["Real motion"] and "aits_seconds" not in res


def test_cli_evaluate_on_another_split(evaluator_dir, eval_corpus, tmp_path, capsys):
    small = ["--checkpoint", "none", "--data", str(eval_corpus), "--evaluator", str(evaluator_dir), "--replications",
             "1", "--no-progress", "--rprecision-batch", "4", "--diversity-times", "5", "--mm-captions", "0"]
    out = tmp_path / "val.json"
    assert main(["evaluate", *small, "--split", "val", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["config"]["split"] == "val"
    assert main(["evaluate", *small, "--split", "nope", "--out", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and "Traceback" not in err and not (tmp_path / "x.json").exists()
