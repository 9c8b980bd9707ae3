"""`smf adapt` end to end on real clips and a tiny student/teacher pair: the file, loading it, resuming exactly,
the clip checks, the command line."""

from __future__ import annotations

import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from stablemofusion.adapters.clips import ClipSkippedWarning, caption_from_name, read_clips
from stablemofusion.adapters.file import Adapter, weights_hash
from stablemofusion.adapters.train import AdaptConfig, adapt
from stablemofusion.core.errors import SMFError

CLIPS = ("dataset-2_walk-turn-left_normal_001", "dataset-1_walk_normal_001", "dataset-2_wave-left-hand_active_001")
CFG = AdaptConfig(rank=2, teacher_steps=4, student_steps=3, batch_size=4, pool=6, replay_prompts=4,
                  checkpoint_every=2, contrast_auto=False)  # contrast whatever the base makes of the captions


@pytest.fixture(scope="module")
def clip_folder(bandai_mini_source, tmp_path_factory) -> Path:
    """Three real BVH clips as a user's folder, with a captions.csv."""
    out = tmp_path_factory.mktemp("clips")
    for name in CLIPS:
        src = next(bandai_mini_source.rglob(f"{name}.bvh"))
        shutil.copy(src, out / f"{name}.bvh")
    (out / "captions.csv").write_text("file,caption\n" + "".join(
        f"{n}.bvh,a person {n.split('_')[1]}s\n" for n in CLIPS) + f"{CLIPS[0]}.bvh,\"someone walks, then turns left\"\n")
    return out


@pytest.fixture(scope="module")
def base(tmp_path_factory, save_tiny_checkpoint, save_tiny_student) -> Path:
    """A tiny student with its teacher in teacher/ and known actions (what `smf adapt` replays)."""
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.text.known import KnownActions

    folder = tmp_path_factory.mktemp("base") / "model"
    mean, std = np.zeros(263), np.full(263, 0.5)
    mean[3] = 0.9
    teacher = save_tiny_checkpoint(folder / "teacher", mean, std)
    save_tiny_student(folder / "staging", teacher, name="teacher")
    for f in (folder / "staging").iterdir():
        f.rename(folder / f.name)
    pipe = MotionPipeline.from_pretrained(folder, device="cpu")
    KnownActions({"wave": ["a person waves", "someone waves a hand"], "bow": ["a person bows"]}, 0.5,
                 pipe.text_cache).save(folder)
    return folder


def test_clips_are_read_with_their_captions(clip_folder):
    clips, source = read_clips(clip_folder, "bandai-namco")
    assert source.endswith("captions.csv")
    assert [c.file for c in clips] == sorted(f"{n}.bvh" for n in CLIPS)
    turn = next(c for c in clips if "turn" in c.file)
    assert turn.captions == ("a person walk-turn-lefts", "someone walks, then turns left")
    assert all(c.features.shape[1] == 263 and c.frames >= 40 for c in clips)
    one, source = read_clips(clip_folder, "bandai-namco", caption="a person moves")
    assert all(c.captions == ("a person moves",) for c in one) and "--caption" in source
    assert caption_from_name("kick_high_02.bvh") == "a person kick high"


def test_bad_clip_folders_are_one_line_errors(clip_folder, bandai_mini_source, tmp_path):
    with pytest.raises(SMFError, match="no .bvh files"):
        read_clips(tmp_path, "bandai-namco")
    folder = tmp_path / "clips"
    shutil.copytree(clip_folder, folder)
    with pytest.raises(SMFError, match="one source of captions"):
        read_clips(folder, "bandai-namco", caption="x", from_names=True)
    (folder / "captions.csv").write_text("file,caption\n" + f"{CLIPS[0]}.bvh,a person runs\n")
    with pytest.raises(SMFError, match="no caption in"):
        read_clips(folder, "bandai-namco")
    (folder / "captions.csv").write_text("file,caption\nmissing.bvh,a person runs\n")
    with pytest.raises(SMFError, match="not .bvh files under"):
        read_clips(folder, "bandai-namco")
    (folder / "captions.csv").write_bytes(b"file,caption\n" + f"{CLIPS[0]}.bvh,".encode() + b"\xff\xfe runs\n")
    with pytest.raises(SMFError, match="not UTF-8 text"):
        read_clips(folder, "bandai-namco")
    (folder / "captions.csv").write_text("file,caption\n" + f"{CLIPS[0]}.bvh,\"{'a' * 131_073}\"\n")
    with pytest.raises(SMFError, match="not a readable CSV file"):  # past the csv module's field limit
        read_clips(folder, "bandai-namco")
    (folder / "captions.csv").unlink()
    with pytest.raises(SMFError, match="no captions for"):
        read_clips(folder, "bandai-namco")
    short = tmp_path / "short"
    short.mkdir()
    shutil.copy(next(bandai_mini_source.rglob("dataset-1_run_normal_001.bvh")), short)  # 0.80 s
    with pytest.raises(SMFError, match="1 of 1 clips are unusable.*run_normal_001.bvh: 0.80 s is too short"):
        read_clips(short, "bandai-namco", caption="a person runs")
    # one unusable clip among usable ones is skipped, and said
    for name in CLIPS[:2]:
        shutil.copy(folder / f"{name}.bvh", short)
    with pytest.warns(ClipSkippedWarning, match="clip skipped: .*run_normal_001.bvh: 0.80 s is too short"):
        clips, _ = read_clips(short, "bandai-namco", caption="a person runs")
    assert len(clips) == 2
    with pytest.raises(SMFError, match="lacks|lack"):  # a rig the joint map does not fit
        read_clips(folder, "mixamo", caption="x")


def test_replay_leaves_out_an_action_that_is_taught_anew(base):
    from stablemofusion.adapters.train import contrast_captions, lexicon_replay, replay_prompts, retaught_actions
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.text.frozen import sentence_embedding

    pipe = MotionPipeline.from_pretrained(base, device="cpu")

    def embed(texts):
        tokens, mask = pipe.text_cache.get_or_compute(texts)
        return sentence_embedding(tokens.float(), mask)

    known = {"walk": ["a person walks", "a man walks ahead"], "run": ["a person runs", "a person jogs"],
             "bow": ["a person bows"]}
    assert retaught_actions(known, ["a person runs", "a person jogs slowly"], embed) == {"run"}
    # an action only some taught captions name is still replayed: the adapter teaches something else
    assert retaught_actions(known, ["a person runs", "a person hops on one leg", "someone hops"], embed) == set()
    candidates = [(a, e) for a, ex in known.items() for e in ex]
    assert replay_prompts(candidates, {"run"}, 10) == ["a person walks", "a person bows", "a man walks ahead"]
    assert replay_prompts(candidates, set(), 2) == ["a person walks", "a person runs"]  # in turn from each action
    # taught captions in the base's words: the words no known caption uses replaced by known ones of the same ending
    known_captions = ["a person walks forward", "an old man walks ahead slowly", "someone is walking", "a person bows"]
    got = contrast_captions(["a person runs forward", "an old man jogs ahead slowly", "someone is running",
                             "a person walks forward"], known_captions, embed)
    assert got == ["a person walks forward", "an old man walks ahead slowly", "someone is walking"]
    assert contrast_captions(["a person bows"], known_captions, embed) == []  # known words only: nothing to contrast
    lexicon = lexicon_replay("bandai")
    assert {a for a, _ in lexicon} >= {"walk", "run", "bow", "wave-both-hands", "kick"}
    assert len(lexicon) > 600 and lexicon == lexicon_replay("bandai")  # two captions per (content, style) pair


def _weights(a: Adapter) -> dict[str, torch.Tensor]:
    return {f"{p}/{k}": v for p, w in a.weights.items() for k, v in w.items()}


def test_adapt_writes_an_adapter_that_loads_and_resumes_exactly(base, clip_folder, tmp_path):
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    torch.set_num_threads(1)
    clips, _ = read_clips(clip_folder, "bandai-namco")
    full = adapt(base, clips, tmp_path / "run.safetensors", CFG, name="run", licence="CC BY-NC 4.0", progress=False)
    loaded = Adapter.load(tmp_path / "run.safetensors")
    assert loaded.info.name == "run" and loaded.info.licence == "CC BY-NC 4.0"
    assert loaded.info.base == {"student": weights_hash(base), "teacher": weights_hash(base / "teacher")}
    taught = {c for clip in clips for c in clip.captions}  # and each said other ways ("a person walks": paraphrases)
    assert taught <= set(loaded.info.actions["run"]) and loaded.info.training["paraphrased"] > 0
    assert len(loaded.info.actions["run"]) == len(taught) + loaded.info.training["paraphrased"]
    assert loaded.info.training["replay_prompts"] == 4 and loaded.info.training["not_replayed"] == []
    assert loaded.info.training["contrast_prompts"] > 0 and 0 <= loaded.info.training["taught_in_domain"] <= 1
    assert set(loaded.weights) == {"student", "teacher"} and all(loaded.weights.values())
    assert (tmp_path / "run.safetensors").stat().st_size < 1 << 20

    # resumed after an interruption in each stage: the same adapter as the uninterrupted run
    for stop in ((1, 2), (2, 2)):
        out = tmp_path / f"resumed-{stop[0]}.safetensors"
        assert adapt(base, clips, out, CFG, name="run", licence="x", progress=False, stop_after=stop) is None
        assert not out.exists()
        again = adapt(base, clips, out, CFG, name="run", licence="x", progress=False, resume=True)
        differ = [k for k, v in _weights(full).items() if not torch.equal(_weights(again)[k], v)]
        assert not differ, (stop, len(differ), differ[:5])
    with pytest.raises(SMFError, match="other clips"):
        adapt(base, clips[:1], tmp_path / "resumed-1.safetensors", CFG, name="run", licence="x", progress=False,
              resume=True, work=tmp_path / "resumed-1.safetensors.work")

    # merged at load: the adapted student differs from the base, its teacher too; the taught captions are known
    pipe = MotionPipeline.from_pretrained(base, device="cpu")
    adapted = MotionPipeline.from_pretrained(base, device="cpu", adapter=tmp_path / "run.safetensors")
    assert adapted.adapters == ("run",) and pipe.adapters == ()
    a = pipe.denoise(["a person runs"], [40], seed=0)
    b = adapted.denoise(["a person runs"], [40], seed=0)
    assert (a - b).abs().max() > 1e-4
    teacher = MotionPipeline.from_pretrained(base, teacher=True, device="cpu", adapter=tmp_path / "run.safetensors")
    assert teacher.adapters == ("run",)
    assert "run" in adapted.known_actions.taught and not pipe.known_actions.taught
    # a prompt clearly closest to the taught action: its model is given the nearest clip caption, and it says so
    from stablemofusion.core.final import TaughtCaptionWarning

    with pytest.warns(TaughtCaptionWarning, match="is answered as"):
        said = adapted(["a man is walking"], seconds=2, seed=0, footskate="off")[0]
    assert said.domain.answer in {c for clip in clips for c in clip.captions}
    assert any("is answered as" in w for w in said.warnings)
    with warnings.catch_warnings():
        warnings.simplefilter("error", TaughtCaptionWarning)  # a clip's own caption is answered as itself: no warning
        own = adapted([said.domain.answer], seconds=2, seed=0, footskate="off")[0]
    np.testing.assert_array_equal(said.joints, own.joints)
    assert pipe(["a man is walking"], seconds=2, seed=0, footskate="off")[0].domain.answer is None

    # the portable runtime: the graphs of the adapted model make its motions and know its captions
    from stablemofusion.cli.main import main
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.backends.onnx_sampling import sample

    graphs = tmp_path / "adapted-graphs"
    assert main(["export", "--onnx", "--checkpoint", str(base), "--adapter", str(tmp_path / "run.safetensors"),
                 "--out", str(graphs)]) == 0
    rt = MotionPipeline.from_pretrained(graphs, backend="onnx", threads=1)
    tokens, mask, _ = rt.encode(["a person runs"])
    m = rt.graphs.model
    got = sample(m, tokens, mask, [40], 0, guidance=m.guidance, sampler=m.sampler, steps=m.steps)
    want = adapted.denoise(["a person runs"], [40], seed=0, engine="eager").numpy()
    np.testing.assert_allclose(got[0], want[0], atol=2e-4, rtol=0)
    assert rt.graphs.manifest["adapters"] == ["run"]
    caption = loaded.info.actions["run"][0]
    assert rt.known_actions.check(caption).out_of_domain == adapted.known_actions.check(caption).out_of_domain
    assert "run" in rt.known_actions.taught
    from safetensors.torch import load_file, save_file

    other = tmp_path / "other"  # the base with one weight changed: another model
    shutil.copytree(base, other)
    weights = load_file(other / "model.safetensors")
    first = next(iter(weights))
    save_file({**weights, first: weights[first] + 1}, str(other / "model.safetensors"))
    with pytest.raises(SMFError, match="another base model"):
        MotionPipeline.from_pretrained(other, device="cpu", adapter=tmp_path / "run.safetensors")


def test_the_command_line_checks_before_it_trains_and_describes_adapters(clip_folder, tiny_checkpoint,
                                                                           save_random_adapter, tmp_path):
    def smf(*args, command="adapt"):
        return subprocess.run([sys.executable, "-m", "stablemofusion.cli.main", command, *args], capture_output=True,
                              text=True, timeout=120)

    r = smf("--data", str(clip_folder), "--out", str(tmp_path / "a.safetensors"))
    assert r.returncode == 2 and "--licence" in r.stderr
    (tmp_path / "a.safetensors").write_bytes(b"")
    r = smf("--data", str(clip_folder), "--out", str(tmp_path / "a.safetensors"), "--licence", "mine")
    assert r.returncode == 2 and "--overwrite" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = smf("--data", str(tmp_path), "--out", str(tmp_path / "b.safetensors"), "--licence", "mine")
    assert r.returncode == 2 and "no .bvh files" in r.stderr and "Traceback" not in r.stderr
    r = smf("--data", str(clip_folder), "--out", str(tmp_path / "c.safetensors"), "--licence", "mine",
            "--target-rescale", "2")
    assert r.returncode == 2 and "--target-rescale is a share in [0, 1], got 2.0" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "c.safetensors").exists()
    r = smf("--adapter", str(save_random_adapter(tmp_path / "kick.safetensors", tiny_checkpoint)), command="info")
    assert r.returncode == 0 and "adapter 'kick'" in r.stdout and "licence of the clips: CC BY 4.0" in r.stdout
    assert "action 'kick': a person kicks" in r.stdout
