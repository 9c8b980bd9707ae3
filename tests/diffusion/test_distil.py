"""The few-step student (`smf distil`): the guidance input, the consistency sampler, exact resume, and the
student loaded through the normal pipeline, `smf generate` and `smf bench`."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from stablemofusion.cli.main import main
from stablemofusion.diffusion.checkpoint import load_checkpoint, read_config
from stablemofusion.diffusion.config import CheckpointConfig, DistilConfig
from stablemofusion.diffusion.distil import distil, drawn_length, masked_huber, skip_grid, student_from_teacher
from stablemofusion.diffusion.schedulers import make_sampler
from stablemofusion.diffusion.solvers import solver_table
from stablemofusion.diffusion.train import TrainConfig, train
from stablemofusion.core.errors import SMFError
from stablemofusion.core.settings import STUDENT_EDIT_STEPS


@pytest.fixture(scope="module")
def corpus(bandai_mini_corpus):
    return bandai_mini_corpus


@pytest.fixture(scope="module")
def text_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("text-cache")


@pytest.fixture(scope="module")
def teacher(corpus, text_cache, tmp_path_factory):
    """A tiny teacher trained for a few steps (its weights are all non-trivial)."""
    out = tmp_path_factory.mktemp("teacher")
    cfg = TrainConfig(preset="tiny", steps=3, batch_size=4, lr=2e-3, checkpoint_every=3, min_frames=16)
    train(corpus, out, cfg, progress=False, text_cache=text_cache)
    (out / "checkpoint" / "notes.txt").write_text("carried into the student\n")
    return out


def _distil_args(teacher, corpus, text_cache, out, *extra):
    return ["distil", "--teacher", str(teacher), "--data", str(corpus), "--out", str(out), "--steps", "6",
            "--batch-size", "4", "--checkpoint-every", "2", "--min-frames", "16", "--text-cache", str(text_cache),
            "--sample-steps", "2", "--warmup", "2", "--lr", "1e-3", "--no-progress", "--threads", "1", *extra]


@pytest.fixture(scope="module")
def student(teacher, corpus, text_cache, tmp_path_factory):
    out = tmp_path_factory.mktemp("student")
    assert main(_distil_args(teacher, corpus, text_cache, out)) == 0
    return out


# --- the sampler --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("steps", [1, 2, 4, 8])
def test_lcm_table_equals_the_diffusers_lcm_scheduler(steps):
    """The coefficient table of the consistency sampler reproduces LCMScheduler on the same noise."""
    table = solver_table("lcm", steps)
    sched = make_sampler("lcm")
    sched.set_timesteps(steps)
    assert table.t.tolist() == sched.timesteps.float().tolist()
    denoise = (lambda x, t: torch.tanh(x) * 0.7 + 1e-3 * t)  # any x0 predictor
    x = torch.randn(2, 12, 5, generator=torch.Generator().manual_seed(1))
    ref, g = x.clone(), torch.Generator().manual_seed(7)
    for t in sched.timesteps:
        ref = sched.step(denoise(ref, t), t, ref, generator=g).prev_sample
    ours, g = x.double(), torch.Generator().manual_seed(7)
    for k in range(steps):
        z = torch.randn(x.shape, generator=g).double() if k < steps - 1 else 0.0
        ours = table.a[k] * ours + table.b[k] * denoise(ours, table.t[k]) + table.d[k] * z
    assert torch.allclose(ours.float(), ref, atol=1e-5)
    assert table.d[-1] == 0 and table.level_x0[-1] == 1  # the last step returns the clean prediction


def test_lcm_timesteps_lie_on_the_distillation_grid():
    grid = set(skip_grid(1000, 50).tolist())
    for steps in (1, 2, 4, 8, 50):
        assert set(solver_table("lcm", steps).t.int().tolist()) <= grid
    with pytest.raises(SMFError, match="at most 50"):
        solver_table("lcm", 51)


# --- the student model ----------------------------------------------------------------------------------------


def test_a_fresh_student_is_its_teachers_conditional_branch(teacher):
    ck = load_checkpoint(teacher)
    s = student_from_teacher(ck).eval()
    assert s.takes_guidance and not ck.model.takes_guidance
    x, t = torch.randn(2, 40, ck.model.motion_dim), torch.tensor([900.0, 20.0])
    tokens, tmask = torch.randn(2, 7, 384), torch.ones(2, 7, dtype=torch.bool)
    with torch.no_grad():
        want = ck.model(x, t, tokens, tmask)
        for w in (1.5, 4.0):
            assert torch.allclose(s(x, t, tokens, tmask, guidance=w), want, atol=1e-6)
        with pytest.raises(SMFError, match="guidance"):
            s(x, t, tokens, tmask)
        for p in s.guidance_embed.parameters():  # once trained, the scale changes the prediction
            p.normal_(0, 0.1)
        assert not torch.allclose(s(x, t, tokens, tmask, guidance=1.5), s(x, t, tokens, tmask, guidance=4.0))


def test_a_student_config_round_trips(teacher):
    cfg = read_config(teacher)
    st = replace(cfg, model=replace(cfg.model, guidance=True), distil=DistilConfig(teacher="/x", sample_steps=3))
    d = json.loads(json.dumps(st.to_dict()))
    back = CheckpointConfig.from_dict(d)
    assert back == st and back.student and back.model.guidance
    assert "distil" not in cfg.to_dict() and "guidance" not in cfg.to_dict()["model"]  # teachers unchanged
    assert not CheckpointConfig.from_dict(cfg.to_dict()).student
    assert st.resume_mismatch(cfg)  # a student never resumes a teacher's run, nor the reverse


def test_masked_huber_ignores_padding():
    pred, target = torch.zeros(1, 4, 2), torch.zeros(1, 4, 2)
    target[0, 3] = 100.0
    mask = torch.tensor([[True, True, True, False]])
    assert masked_huber(pred, target, mask, 0.001) == 0
    target[0, 0] = 1.0
    assert masked_huber(pred, target, mask, 0.001) > 0


# --- the run --------------------------------------------------------------------------------------------------


def test_distil_writes_a_student_checkpoint(student, teacher):
    cfg = read_config(student)
    assert cfg.student and cfg.model.guidance and cfg.step == 6
    assert cfg.distil.sample_steps == 2 and cfg.distil.teacher == str((teacher / "checkpoint").resolve())
    ck_dir = student / "checkpoint"
    assert (ck_dir / "notes.txt").read_text() == "carried into the student\n"  # the teacher folder's extra files
    t = load_checkpoint(teacher)
    assert np.array_equal(np.load(ck_dir / "Mean.npy"), t.mean) and np.array_equal(np.load(ck_dir / "Std.npy"), t.std)
    log = (student / "log.csv").read_text().splitlines()
    assert log[0] == "step,loss,lr,seconds,samples_per_s" and len(log) == 7
    s = load_checkpoint(student)  # the target network (EMA)
    moved = [k for k, v in s.model.state_dict().items() if k in t.model.state_dict()
             and not torch.equal(v, t.model.state_dict()[k])]
    assert moved and any(p.abs().sum() > 0 for p in s.model.guidance_embed.mlp[2].parameters())


def test_a_student_does_not_take_its_teachers_default_guidance(teacher, corpus, text_cache, tmp_path):
    """A teacher's default scale is for its two-pass guidance; the student takes the scale as input and starts
    with the package's default."""
    tuned = tmp_path / "tuned"
    assert main(["export", "--checkpoint", str(teacher), "--out", str(tuned), "--guidance", "1.0",
                 "--dtype", "float32"]) == 0
    out = tmp_path / "student"
    assert main(_distil_args(tuned, corpus, text_cache, out, "--steps", "1", "--checkpoint-every", "1")) == 0
    assert read_config(tuned).guidance == 1.0 and read_config(out).guidance is None


def test_a_killed_distillation_resumes_exactly(teacher, corpus, text_cache, student, tmp_path):
    part = tmp_path / "part"
    assert main(_distil_args(teacher, corpus, text_cache, part, "--stop-after", "4")) == 0
    assert read_config(part).step == 4
    assert main(_distil_args(teacher, corpus, text_cache, part, "--resume")) == 0
    losses = (lambda run: [r.split(",")[1] for r in (run / "log.csv").read_text().splitlines()[1:]])
    assert losses(part) == losses(student)  # the same 6 losses, bit for bit
    for ema in (True, False):
        a, b = load_checkpoint(student, ema=ema).model.state_dict(), load_checkpoint(part, ema=ema).model.state_dict()
        assert all(torch.equal(a[k], b[k]) for k in a)


def test_guidance_lr_scale_speeds_up_only_the_guidance_embedding(teacher, corpus, text_cache, tmp_path):
    """--guidance-lr-scale multiplies the learning rate of the zero-initialised guidance embedding alone (its own
    AdamW group): its last layer moves much further from zero in the same steps."""
    fast = tmp_path / "fast"
    assert main(_distil_args(teacher, corpus, text_cache, fast, "--guidance-lr-scale", "20", "--stop-after", "2")) == 0
    assert read_config(fast).distil.guidance_lr_scale == 20.0
    base = tmp_path / "base"
    assert main(_distil_args(teacher, corpus, text_cache, base, "--stop-after", "2")) == 0
    a, b = (load_checkpoint(r, ema=False).model for r in (fast, base))
    size = (lambda m: sum(p.abs().sum() for p in m.guidance_embed.mlp[2].parameters()).item())
    assert size(a) > 5 * size(b) > 0
    state = torch.load(fast / "checkpoint" / "training_state.pt", weights_only=False)
    assert [g["lr_scale"] for g in state["optimizer"]["param_groups"]] == [1.0, 20.0]


def test_a_run_saved_with_one_optimizer_group_is_refused_on_resume(teacher, corpus, text_cache, tmp_path, capsys):
    """A run saved before the guidance embedding had its own AdamW group: a one-line error, not torch's ValueError."""
    run = tmp_path / "old"
    assert main(_distil_args(teacher, corpus, text_cache, run, "--stop-after", "2")) == 0
    path = run / "checkpoint" / "training_state.pt"
    state = torch.load(path, weights_only=False)
    groups = state["optimizer"]["param_groups"]
    merged = {**groups[0], "params": groups[0]["params"] + groups[1]["params"]}
    merged.pop("lr_scale")
    state["optimizer"]["param_groups"] = [merged]
    torch.save(state, path)
    capsys.readouterr()
    assert main(_distil_args(teacher, corpus, text_cache, run, "--resume")) == 2
    err = capsys.readouterr().err.strip()
    assert "saved by an older `smf distil`" in err and "\n" not in err


def test_distil_refuses_bad_inputs(teacher, student, corpus, text_cache, tmp_path, capsys):
    assert main(_distil_args(student, corpus, text_cache, tmp_path / "a")) == 2  # a student is no teacher
    assert "already a distilled student" in capsys.readouterr().err
    assert main(_distil_args(teacher, corpus, text_cache, tmp_path / "b", "--loss", "l1")) == 2
    assert main(_distil_args(teacher, corpus, text_cache, tmp_path / "e", "--guidance-lr-scale", "0")) == 2
    assert main(_distil_args(teacher, corpus, text_cache, tmp_path / "c", "--resume")) == 2  # nothing to resume
    with pytest.raises(SMFError, match="teacher"):
        distil(corpus, tmp_path / "d", DistilConfig(teacher=""))


# --- regression on the teacher's samples (--method regression) -------------------------------------------------


def test_regression_targets_and_predictions_are_the_pipelines_samples(teacher, student):
    """What regression distillation compares is what the pipeline draws: the teacher's deterministic sample and
    the student's consistency sample from the same noise (so the student learns the teacher's noise-to-motion map)."""
    from stablemofusion.diffusion.distil import student_sample, teacher_sample
    from stablemofusion.diffusion.sampling import Noise
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    prompts, lengths, seeds = ["a person walks", "a person runs"], [40, 48], [3, 4]
    for folder, w, sampler, steps in ((teacher, 1.0, "dpmsolver++-karras", 3), (teacher, 2.0, "ddim", 2),
                                      (student, 1.5, "lcm", 2)):
        pipe = MotionPipeline.from_pretrained(folder, device="cpu")
        want = pipe.denoise(prompts, lengths, seed=seeds, guidance_scale=w, sampler=sampler, steps=steps)
        c = pipe
        tokens, tmask = c.encode_text(prompts)
        mask = torch.arange(max(lengths))[None] < torch.tensor(lengths)[:, None]
        table = c.solver(sampler, steps)
        noise = Noise(seeds, lengths, want.shape[-1], "cpu")  # the pipeline's draws, in its order
        eps, step_noise = noise.draw(), noise.draw(steps)
        drop, ws = torch.zeros(2, dtype=torch.bool), torch.full((2,), w)
        with torch.no_grad():
            if pipe.student:
                got = student_sample(c.model, eps, tokens, tmask, drop, mask, ws, table, step_noise)
            else:
                got = teacher_sample(c.model, eps, tokens, tmask, drop, mask, ws, table)
        got = c.denormalise(got)
        for i, n in enumerate(lengths):
            assert torch.allclose(got[i, :n], want[i, :n], atol=1e-4), (folder.name, sampler)


def _regression_args(teacher, student, corpus, text_cache, out, *extra):
    return _distil_args(teacher, corpus, text_cache, out, "--method", "regression", "--init-from", str(student),
                        "--guidance-min", "1", "--guidance-max", "1", "--sample-steps", "1", "--teacher-steps", "3",
                        "--target-decay", "0", *extra)


def test_regression_distillation_moves_the_student_towards_the_teacher(teacher, student, corpus, text_cache,
                                                                     tmp_path):
    """A student started away from the teacher (its weights perturbed) ends closer to the teacher's samples for
    the same noise (the fixture student is already within rounding of this tiny teacher, so a few steps from it
    would show rounding, not learning)."""
    import shutil

    from safetensors.torch import load_file, save_file

    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    far = tmp_path / "far"
    shutil.copytree(student, far)
    weights = load_file(far / "checkpoint" / "ema.safetensors")
    g = torch.Generator().manual_seed(0)
    save_file({k: v + 0.02 * torch.randn(v.shape, generator=g) if v.is_floating_point() else v
               for k, v in weights.items()}, far / "checkpoint" / "ema.safetensors")
    out = tmp_path / "reg"
    assert main(_regression_args(teacher, far, corpus, text_cache, out, "--steps", "12", "--lr", "1e-3")) == 0
    cfg = read_config(out)
    assert cfg.student and cfg.distil.method == "regression" and cfg.distil.init_from == str(far)
    assert cfg.guidance == 1.0  # regressed on the teacher at one scale: that scale is its default
    prompts, lengths, seeds = ["a person walks", "a person runs", "a person jumps"], [40, 48, 44], [5, 6, 7]
    target = MotionPipeline.from_pretrained(teacher, device="cpu").denoise(
        prompts, lengths, seed=seeds, guidance_scale=1.0, sampler="dpmsolver++-karras", steps=3)
    gap = {}
    for name, folder in (("before", far), ("after", out)):
        got = MotionPipeline.from_pretrained(folder, device="cpu").denoise(prompts, lengths, seed=seeds, steps=1,
                                                                           guidance_scale=1.0)
        gap[name] = sum(float(((got[i, :n] - target[i, :n]) ** 2).mean()) for i, n in enumerate(lengths))
    assert gap["after"] < 0.5 * gap["before"], gap  # 0.24-0.26 with one or two threads
    assert gap["after"] < 0.8 * gap["before"], gap


@pytest.mark.parametrize("mix", [[], ["--length-mix", "0.5"]])
def test_a_killed_regression_run_resumes_exactly(teacher, student, corpus, text_cache, tmp_path, mix):
    whole, part = tmp_path / "whole", tmp_path / "part"
    assert main(_regression_args(teacher, student, corpus, text_cache, whole, "--steps", "4", *mix)) == 0
    assert main(_regression_args(teacher, student, corpus, text_cache, part, "--steps", "4", "--stop-after", "2",
                                 *mix)) == 0
    assert main(_regression_args(teacher, student, corpus, text_cache, part, "--steps", "4", "--resume", *mix)) == 0
    losses = (lambda run: [r.split(",")[1] for r in (run / "log.csv").read_text().splitlines()[1:]])
    assert losses(part) == losses(whole) and len(losses(whole)) == 4


def test_drawn_lengths_are_uniform_multiples_of_4_on_a_fraction_of_steps():
    """--length-mix P: a fraction P of steps samples at one length, a multiple of 4 frames in [min, max] drawn
    uniformly; the rest (and every step at P = 0) keep the clips' lengths; the draw is a function of (seed, step)."""
    cfg = DistilConfig(teacher="t", method="regression", length_mix=0.5)
    draws = [drawn_length(cfg, s, 39, 196) for s in range(2000)]
    got = [n for n in draws if n is not None]
    assert 0.45 < len(got) / len(draws) < 0.55
    assert all(n % 4 == 0 and 40 <= n <= 196 for n in got) and {40, 196} <= set(got)
    assert abs(np.mean(got) - 118) < 3  # uniform over 40, 44, ..., 196
    assert draws == [drawn_length(cfg, s, 39, 196) for s in range(2000)]
    assert draws != [drawn_length(replace(cfg, seed=1), s, 39, 196) for s in range(2000)]
    assert all(drawn_length(replace(cfg, length_mix=0.0), s, 39, 196) is None for s in range(100))
    assert all(drawn_length(replace(cfg, length_mix=1.0), s, 39, 196) is not None for s in range(100))


def test_length_mix_samples_teacher_and_student_at_the_drawn_length(teacher, student, corpus, text_cache, tmp_path,
                                                                     monkeypatch):
    """The steps drawn by --length-mix run the teacher and the student on noise of that length with every frame
    valid; the others on the clips' lengths (their padding masked)."""
    import stablemofusion.diffusion.distil as D

    seen = {"teacher": [], "student": []}

    def spy(name, fn):
        def wrapped(model, eps, tokens, tmask, drop, mask, *rest):
            seen[name].append((tuple(eps.shape), mask.shape[1], bool(mask.all())))
            return fn(model, eps, tokens, tmask, drop, mask, *rest)
        return wrapped

    monkeypatch.setattr(D, "teacher_sample", spy("teacher", D.teacher_sample))
    monkeypatch.setattr(D, "student_sample", spy("student", D.student_sample))
    assert main(_regression_args(teacher, student, corpus, text_cache, tmp_path / "mix", "--steps", "8",
                                 "--length-mix", "0.5")) == 0
    cfg = read_config(tmp_path / "mix")
    assert cfg.distil.length_mix == 0.5
    drawn = [drawn_length(cfg.distil, s, 16, cfg.max_frames) for s in range(8)]
    assert any(n is None for n in drawn) and any(n is not None for n in drawn)
    assert seen["teacher"] == seen["student"] and len(seen["teacher"]) == 8
    for n, (shape, frames, full) in zip(drawn, seen["teacher"]):
        assert shape[:2] == (4, frames)
        if n is not None:
            assert frames == n and full
        else:
            assert frames <= 196


def test_regression_refuses_bad_inputs(teacher, student, corpus, text_cache, tmp_path, capsys):
    capsys.readouterr()
    for extra, says in ((["--teacher-sampler", "sde-dpmsolver++-karras"], "--teacher-sampler must be deterministic"),
                        (["--teacher-steps", "0"], "--teacher-steps"), (["--method", "progressive"], "--method"),
                        (["--length-mix", "1.5"], "--length-mix must be in [0, 1]")):
        assert main(_regression_args(teacher, student, corpus, text_cache, tmp_path / "x", *extra)) == 2
        err = capsys.readouterr().err.strip()
        assert says in err and "\n" not in err
    assert main(_distil_args(teacher, corpus, text_cache, tmp_path / "y", "--method", "regression",
                             "--init-from", str(teacher))) == 2  # a teacher is no student to start from
    assert "not a distilled student" in capsys.readouterr().err
    assert main(_distil_args(teacher, corpus, text_cache, tmp_path / "z", "--length-mix", "0.5")) == 2
    assert "--length-mix needs --method regression" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y" / "checkpoint").exists()
    assert not (tmp_path / "z").exists()


# --- the student through the pipeline, smf generate and smf bench ---------------------------------------------


def _count_forwards(model):
    calls = []
    orig = model.denoise

    def counting(x, t, cond, mask=None):
        calls.append(x.shape[0])
        return orig(x, t, cond, mask)

    model.denoise = counting
    return calls


def test_the_pipeline_samples_a_student_with_one_forward_per_step(student):
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    pipe = MotionPipeline.from_pretrained(student, device="cpu")
    assert pipe.student and pipe.settings().sampler == "lcm" and pipe.settings().steps == 2
    calls = _count_forwards(pipe.model)
    a = pipe.denoise(["a person walks", "a person runs"], [40, 48], seed=0)
    assert calls == [2, 2]  # 2 steps, batch 2: no unconditional pass
    b = pipe.denoise(["a person walks", "a person runs"], [40, 48], seed=0, guidance_scale=4.0)
    assert not torch.allclose(a, b)  # the scale is an input
    calls.clear()
    pipe.denoise(["a person walks"], [40], seed=0, steps=3, sampler="ddim")  # the flags still work
    assert calls == [1, 1, 1]
    calls.clear()
    res = pipe(["a person walks"], seconds=2.0, seed=0)  # end to end: rigid stage included
    assert calls == [1, 1] and res[0].features.shape[0] == 40


def test_teacher_defaults_are_unchanged(teacher):
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    pipe = MotionPipeline.from_pretrained(teacher, device="cpu")
    assert not pipe.student and pipe.settings().steps == 10 and pipe.settings().sampler == "sde-dpmsolver++-karras"
    calls = _count_forwards(pipe.model)
    pipe.denoise(["a person walks"], [40], seed=0, steps=2)
    assert calls == [2, 2]  # classifier-free guidance: both passes in one batch


def test_smf_generate_and_bench_use_the_students_defaults(student, tmp_path, capsys):
    out = tmp_path / "gen"
    assert main(["generate", "a person walks forward", "--checkpoint", str(student), "--out", str(out),
                 "--format", "npy,json", "--seconds", "2", "--device", "cpu"]) == 0
    meta = json.loads(next(out.glob("*.json")).read_text())
    assert meta["sampler"] == "lcm" and meta["steps"] == 2 and meta["student"] is True
    capsys.readouterr()
    assert main(["bench", "--checkpoint", str(student), "--batch-sizes", "1", "--repeats", "1", "--frames", "40",
                 "--engine", "fast", "--device", "cpu"]) == 0
    report = json.loads(capsys.readouterr().out.split("\n", 1)[1])
    assert report["student"] and report["results"][0]["sampler"] == "lcm" and report["results"][0]["steps"] == 2


def test_a_student_edits_streams_and_makes_timelines(student):
    """The tasks built on hooks (imputation in x_t, x0 constraints) run with the consistency sampler too."""
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    pipe = MotionPipeline.from_pretrained(student, device="cpu")
    calls = _count_forwards(pipe.model)
    first = pipe(["a person walks"], seconds=3.0, seed=0)[0]
    calls.clear()
    for impose in ("x0", "xt"):
        r = pipe.edit("a person runs", first.features, "prefix", keep_start=1.0, seed=0, impose=impose)
        assert np.abs(r.joints[:20] - first.joints[:20]).max() < 0.01  # the kept second is the source's (1 cm)
    assert calls == [1] * 2 * STUDENT_EDIT_STEPS  # an edit takes more steps than the student's own 2
    calls.clear()
    pipe.edit("a person runs", first.features, "prefix", keep_start=1.0, seed=0, steps=3)
    assert calls == [1, 1, 1]  # unless they are given
    src = first.features
    long = pipe.timeline([("a person walks", 8.0), ("a person runs", 4.0)], seed=0)
    assert long.features.shape[0] == 240
    stream = pipe.stream("a person walks", seed=0)
    assert next(stream).features.shape[1] == src.shape[1]
