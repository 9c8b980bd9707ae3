"""Length from text: the estimator beats the constant median, the shipped one knows walks from raised hands,
and the pipeline uses it when no length is given."""

import json

import numpy as np
import pytest
import torch

from stablemofusion.cli.main import main
from stablemofusion.core.errors import SMFError
from stablemofusion.core.noise import length_level
from stablemofusion.pipelines.motion_pipeline import MotionPipeline, default_model_path
from stablemofusion.text.length import LengthConfig, LengthEstimator


@pytest.fixture(scope="module")
def corpus(bandai_mini_corpus):
    return bandai_mini_corpus


def test_bins_and_median_prediction():
    cfg = LengthConfig(min_frames=40, max_frames=196, unit=4)
    assert cfg.bins == 40 and list(cfg.bin_of(np.array([10, 40, 43, 44, 196, 500]))) == [0, 0, 0, 1, 39, 39]
    model = LengthEstimator(cfg)
    with torch.no_grad():  # a distribution with 30% on 60 frames and 70% on 100: the median is 100
        model.net[-1].weight.zero_()
        model.net[-1].bias.fill_(-30.0)
        model.net[-1].bias[cfg.bin_of(np.array([60]))[0]] = np.log(0.3)
        model.net[-1].bias[cfg.bin_of(np.array([100]))[0]] = np.log(0.7)
    assert model.median_frames(torch.zeros(3, cfg.in_dim)).tolist() == [100, 100, 100]


def test_train_length_beats_the_constant_median(corpus, tmp_path, capsys):
    out = tmp_path / "model"
    assert main(["train-length", "--data", str(corpus), "--out", str(out), "--steps", "300"]) == 0  # sentence
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["train"]["mae_frames"] < 0.75 * report["train"]["baseline_mae_frames"]
    assert (out / "length.safetensors").is_file() and not (out / "text-cache").exists()
    meta = json.loads((out / "length.json").read_text())
    assert meta["config"]["min_frames"] == 40 and "train" in meta["metrics"]
    assert LengthEstimator.load(out).config == LengthConfig(**meta["config"])


def test_text_inputs_copy_the_models_text_transformer(corpus, tmp_path, capsys, save_tiny_checkpoint):
    path = save_tiny_checkpoint(tmp_path / "c", np.zeros(263), np.full(263, 0.1))
    assert main(["train-length", "--data", str(corpus), "--out", str(path), "--steps", "300", "--inputs", "text"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["train"]["mae_frames"] < 0.75 * report["train"]["baseline_mae_frames"]
    est = LengthEstimator.load(path)
    pipe = MotionPipeline.from_pretrained(path, device="cpu")
    assert est.config.inputs == "text" and est.config.in_dim == pipe.model.text_config.latent
    for k, v in pipe.model.text.state_dict().items():  # the copy (stored in float16) is the model's transformer
        torch.testing.assert_close(est.text.state_dict()[k], v.half().float())
    prompts = ["a person walks forward", "a person raises both hands"]
    tokens, mask = pipe.encode_text(prompts)
    with torch.no_grad():
        h = pipe.model.text(tokens, mask)
    pooled = (h * mask[..., None]).sum(1) / mask.sum(1, keepdim=True)
    torch.testing.assert_close(est.features(tokens, mask), pooled / pooled.norm(dim=-1, keepdim=True),
                               atol=1e-3, rtol=0)
    assert pipe.predict_seconds(prompts) == [int(f) / pipe.fps for f in est.predict_frames(tokens, mask)]
    est.train()  # only the MLP trains: the copied transformer stays in eval mode, without gradients
    assert not est.text.training and not any(p.requires_grad for p in est.text.parameters())


def test_both_inputs_put_the_sentence_embedding_beside_the_text_features():
    from stablemofusion.text.frozen import sentence_embedding
    from stablemofusion.text.length import TEXT_DIMS

    dims = dict(in_dim=384, latent=32, layers=1, heads=2, ff=64, max_tokens=77)
    assert set(dims) == set(TEXT_DIMS)
    est = LengthEstimator(LengthConfig(in_dim=384 + 32, inputs="both", text=dims))
    text_only = LengthEstimator(LengthConfig(in_dim=32, inputs="text", text=dims)).copy_text(est.text)
    tokens, mask = torch.randn(2, 5, 384), torch.tensor([[1, 1, 1, 0, 0], [1, 1, 1, 1, 1]], dtype=torch.bool)
    f = est.features(tokens, mask)
    assert f.shape == (2, 416) and torch.equal(f[:, :384], sentence_embedding(tokens, mask))
    torch.testing.assert_close(f[:, 384:], text_only.features(tokens, mask))
    assert est.predict_frames(tokens, mask).shape == (2,)


def test_text_inputs_need_a_model(corpus, tmp_path, capsys):
    assert main(["train-length", "--data", str(corpus), "--out", str(tmp_path / "empty"), "--steps", "10",
                 "--inputs", "both"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--inputs both" in err and "--inputs sentence" in err
    assert not (tmp_path / "empty" / "length.safetensors").exists()
    with pytest.raises(SMFError, match="needs the text transformer"):
        LengthConfig(inputs="text")
    with pytest.raises(SMFError, match="inputs must be one of"):
        LengthConfig(inputs="words")


def test_shipped_estimator_and_pipeline_lengths():
    pipe = MotionPipeline.from_pretrained(device="cpu")
    prompts = ["a person walks forward", "a person raises both hands"]
    walk, hands = pipe.predict_seconds(prompts)
    assert walk >= 2 * hands  # corpus medians: walk 149 frames, raise-up-both-hands 57
    # a motion takes the quantile of its seed and stream: one seed for the call, item k stream k
    r = pipe(prompts, steps=2, seed=0)
    drawn = pipe.backend.predict_seconds(prompts, [length_level(0, 0), length_level(0, 1)])
    assert [len(x.joints) for x in r] == [round(s * pipe.fps) // 4 * 4 for s in drawn]
    assert pipe.backend.predict_seconds(prompts, [0.5, 0.5]) == [walk, hands]
    given = pipe("a person walks forward", seconds=3.0, steps=2, seed=0)[0]
    assert len(given.joints) == 60
    meta = json.loads((default_model_path() / "length.json").read_text())
    assert meta["metrics"]["test"]["reduction"] >= 0.25  # the bar: 25% lower error than the median


def test_seeds_draw_their_lengths_from_the_length_models_distribution():
    """Different seeds, different lengths, as real takes of one action differ: each the distribution's quantile at
    its seed's level, the same alone as in a batch of seeds, and a higher level never shorter."""
    pipe = MotionPipeline.from_pretrained(backend="onnx")
    prompt = "a man runs forward"
    batch = [r.frames for r in pipe([prompt] * 6, seed=list(range(6)), footskate="off")]
    alone = [pipe(prompt, seed=s, footskate="off")[0].frames for s in range(6)]
    assert batch == alone and len(set(batch)) >= 3
    levels = np.linspace(0.02, 0.98, 25)
    frames = [round(s * pipe.fps) for s in pipe.backend.predict_seconds([prompt] * 25, list(levels))]
    assert frames == sorted(frames) and frames[-1] - frames[0] >= 20
    # the torch estimator gives the graph's lengths at any level
    torch_pipe = MotionPipeline.from_pretrained(device="cpu")
    assert torch_pipe.backend.predict_seconds([prompt] * 25, list(levels)) == pipe.backend.predict_seconds(
        [prompt] * 25, list(levels))
    # a length given is kept, whatever the seed
    assert {pipe(prompt, seconds=3, seed=s, footskate="off")[0].frames for s in range(4)} == {60}


def test_an_estimator_of_another_text_encoder_is_refused(tmp_path, save_tiny_checkpoint):
    import shutil

    path = save_tiny_checkpoint(tmp_path / "c", np.zeros(263), np.full(263, 0.1))
    shutil.copy(default_model_path() / "length.safetensors", path / "length.safetensors")
    meta = json.loads((default_model_path() / "length.json").read_text())
    meta["config"]["text_encoder"] = "clip:/somewhere"
    (path / "length.json").write_text(json.dumps(meta))
    with pytest.raises(SMFError, match="trained with the text encoder clip:/somewhere"):
        MotionPipeline.from_pretrained(path, device="cpu")


def test_models_without_an_estimator(tmp_path, save_tiny_checkpoint):
    path = save_tiny_checkpoint(tmp_path / "c", np.zeros(263), np.full(263, 0.1))
    pipe = MotionPipeline.from_pretrained(path, device="cpu")
    with pytest.raises(SMFError, match="no length estimator"):
        pipe.predict_seconds("a person walks")
    assert len(pipe("a person walks", steps=1, seed=0)[0].joints) == 80  # DEFAULT_SECONDS
