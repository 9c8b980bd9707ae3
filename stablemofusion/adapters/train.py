"""``smf adapt``: teach a model new moves from a user's clips, as a small low-rank adapter, on a CPU in minutes.

The default path runs a 1-step student distilled from a teacher; a student cannot learn from clips directly
(regressing its one step onto clips teaches the average clip), so both are adapted:

1. **Teacher.** LoRA layers (:mod:`.lora`) on the frozen teacher, trained with its own diffusion loss (x0
   prediction, masked MSE, condition drop) on random crops of the user's clips. Most of each batch (``replay``) is
   *replay*: the base teacher's own samples for captions of the actions the base knows (its ``actions.json``;
   captions from the lexicon of its corpus, or the examples), except an action most taught captions name, so
   that what it knew stays (prior preservation, as in DreamBooth); and for the taught captions said in the base's
   own words (:func:`contrast_captions`), so that the words that differ, not the subjects and styles the taught
   captions share with known ones, carry the new move.
2. **Student.** LoRA layers on the frozen student, regressed (as ``smf distil --method regression``) onto a
   fixed pool of targets: for the taught captions, the adapted teacher's deterministic samples from drawn
   noise; for the replay captions, the base student's own outputs from drawn noise (so it keeps them exactly).
3. The adapter file: both parts' LoRA weights (float16), the actions and captions, the base weights' hashes
   and the licence (:mod:`.file`).

Runs through accelerate like ``smf train``. Every random draw of step ``s`` of stage ``k`` is seeded from
(seed, k, s) and the replay and the targets are functions of the seed and the weights, so a run resumed from
its work folder (``--resume``) equals the uninterrupted run on a CPU.
"""

from __future__ import annotations

import csv
import json
import math
import re
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from ..diffusion.config import LENGTH_MULTIPLE
from ..core.errors import SMFError
from ..core.limits import SEED_RANGE
from ..data.captions import paraphrases
from .clips import Clip
from .file import Adapter, AdapterInfo, weights_hash
from .lora import LoraConfig, add_lora, load_lora_state, lora_state, no_fast_path

STATE_FILE = "state.pt"
LOG_HEADER = "stage,step,loss,lr,seconds"
CONTRAST_PER_PAIR = 8  # lexicon captions per (content, style) pair: the known words of contrast_captions
CONTRAST_NEAREST = 32  # known words tried in place of an unknown one (the closest alone, of the same ending)
WORD = re.compile(r"[a-z]+(?:['-][a-z]+)*")  # a word of a caption (lower case)
WORD_ENDINGS = ("ing", "ly", "ed", "er", "s")  # a replacing word ends as the replaced one
CONTRAST_IN_DOMAIN = 0.9  # share of taught captions the base's out-of-domain check passes, from which contrast is on
REPLAY_MATCH = 0.75  # a taught caption this similar (cosine of sentence embeddings) to a known example names its action


@dataclass
class AdaptConfig:
    """Settings of an adaptation (saved in the adapter). ``replay``: share of each batch from the base's replay."""

    rank: int = 16
    alpha: float = 16.0
    # adapt the text transformer's layers too: with the contrast replay, measured (docs/adapters.md), they carry the
    # taught words to prompts of other subjects and styles; without it they pulled walks towards runs
    text_layers: bool = True
    teacher_steps: int = 500
    student_steps: int = 300
    batch_size: int = 32
    teacher_lr: float = 1e-3
    student_lr: float = 5e-4
    replay: float = 0.75  # measured: 0.5 kept fewer of the base's walks (docs/adapters.md)
    replay_prompts: int = 512  # captions of the base's actions replayed (spread over its actions)
    contrast: int = 8  # replayed samples of each taught caption said in the base's words (contrast_captions); 0: none
    # contrast only when the base takes (nearly) all taught captions for ones it knows (CONTRAST_IN_DOMAIN), else none:
    # measured (docs/adapters.md), it taught running to a base that walked for it, and hopping less well
    contrast_auto: bool = True
    lexicon: str = "bandai"  # the base corpus's caption lexicon (replayed captions); "": its known-action examples
    # other ways to say each taught caption, from that lexicon's phrasings (data.captions.paraphrases; 0: none), so that
    # the move answers to people's words, not only to the captions' (docs/adapters.md)
    paraphrases: int = 8
    pool: int = 512  # student targets per side (taught captions, replay)
    target_guidance: float | None = None  # guidance of the adapted teacher for the student's targets (None: its own)
    # guidance rescale of those targets (rescale_guidance; 0: none): measured (docs/adapters.md), plain guidance made
    # the taught running far faster than the clips, full rescale (1) slower; a half comes closest to their speed
    target_rescale: float = 0.5
    cond_drop: float = 0.1
    grad_clip: float = 1.0
    seed: int = 0
    checkpoint_every: int = 100

    def to_dict(self) -> dict:
        return asdict(self)

    def check(self) -> "AdaptConfig":
        if self.rank < 1 or self.alpha <= 0:
            raise SMFError(f"--rank must be at least 1 and alpha positive, got {self.rank}, {self.alpha}")
        if self.teacher_steps < 0 or self.student_steps < 0 or self.batch_size < 2:
            raise SMFError("--teacher-steps and --student-steps must not be negative, --batch-size at least 2")
        if not 0 <= self.target_rescale <= 1:
            raise SMFError(f"--target-rescale is a share in [0, 1], got {self.target_rescale}")
        if not 0 <= self.replay < 1:
            raise SMFError(f"--replay is a share of each batch in [0, 1), got {self.replay}")
        if self.contrast < 0 or self.paraphrases < 0:
            raise SMFError(f"--contrast and --paraphrases must not be negative, got {self.contrast}, "
                           f"{self.paraphrases}")
        if self.teacher_lr <= 0 or self.student_lr <= 0 or self.pool < 1 or self.checkpoint_every < 1:
            raise SMFError("learning rates, --pool and --checkpoint-every must be positive")
        return self


def _mix(*ints: int) -> int:
    from ..diffusion.train import _mix as mix

    return mix(*ints)


def _pad(items: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """(T_i, D) tensors -> (B, max T, D) zero-padded and the (B, max T) bool mask of valid frames."""
    T = max(len(x) for x in items)
    out = torch.zeros(len(items), T, items[0].shape[-1])
    mask = torch.zeros(len(items), T, dtype=torch.bool)
    for i, x in enumerate(items):
        out[i, :len(x)] = x
        mask[i, :len(x)] = True
    return out, mask


def _frames(n: int, lo: int, hi: int) -> int:
    """``n`` frames within [lo, hi], a multiple of LENGTH_MULTIPLE."""
    return max(lo, min(hi, n)) // LENGTH_MULTIPLE * LENGTH_MULTIPLE


def named_actions(known: dict[str, list[str]], captions: list[str], embed: Callable) -> list[str | None]:
    """The known action each caption names: that of its closest example sentence when their similarity (cosine of
    sentence embeddings) is at least REPLAY_MATCH, else None."""
    examples = [(a, e) for a, ex in known.items() for e in ex]
    if not examples or not captions:
        return [None] * len(captions)
    best, which = (embed([e for _, e in examples]) @ embed(captions).T).max(dim=0)  # (C,): unit embeddings
    return [examples[i][0] if s >= REPLAY_MATCH else None for s, i in zip(best.tolist(), which.tolist())]


def retaught_actions(known: dict[str, list[str]], taught: list[str], embed: Callable) -> set[str]:
    """The known actions that most taught captions name (:func:`named_actions`): the adapter teaches them anew, so
    the base's answer to them is not replayed."""
    named = [a for a in named_actions(known, taught, embed) if a is not None]
    return {a for a in set(named) if 2 * named.count(a) >= len(taught)}


def lexicon_replay(lexicon: str, per_pair: int = 2, seed: str = "replay", actions=None) -> list[tuple[str, str]]:
    """(content, caption) for every (content, style) pair of the base's corpus lexicon: ``per_pair`` captions
    each, from the caption grammar its training captions came from (subjects, styles and details as users write
    them), the pairs' first captions first. ``actions``: only these contents (None: all)."""
    from ..data.captions import captions_for
    from ..data.lexicon import load_lexicon

    lex = load_lexicon(lexicon)
    pairs = [[(c, text) for text, _ in captions_for(c, s, per_pair, seed=f"{seed}-{d}", lexicon=lexicon)]
             for d, (contents, styles) in lex.datasets.items() for c in contents for s in styles
             if actions is None or c in actions]
    return [p[k] for k in range(per_pair) for p in pairs if k < len(p)]


def replay_prompts(candidates: list[tuple[str, str]], skip: set[str], limit: int) -> list[str]:
    """Up to ``limit`` distinct captions of ``candidates`` ((action, caption) pairs), taken in turn from each
    action, without the actions in ``skip``."""
    by_action: dict[str, list[str]] = {}
    for a, text in candidates:
        if a not in skip and text not in by_action.get(a, []):
            by_action.setdefault(a, []).append(text)
    out, i = [], 0
    while len(out) < limit and any(i < len(v) for v in by_action.values()):
        out += [v[i] for v in by_action.values() if i < len(v)]
        i += 1
    return out[:limit]


def _ending(word: str) -> str:
    """The inflection ``word`` ends with ("is" and "was" end with none)."""
    return next((e for e in WORD_ENDINGS if word.endswith(e) and len(word) > len(e) + 2), "")


def contrast_captions(taught: list[str], known_captions: list[str], embed: Callable,
                      nearest: int = CONTRAST_NEAREST) -> list[str]:
    """Each taught caption said in the base's own words: every word that no caption of ``known_captions`` uses is
    replaced, one after the other, by the known word that keeps the caption closest to the taught one (cosine of
    sentence embeddings), among the ``nearest`` known words closest to it alone with the same ending ("runs" ->
    "walks", "running" -> "walking"). Captions of known words only give none. The base's answers to them are
    what the adapter must tell apart from the taught captions: the words that differ name the new move."""
    vocab = sorted({w for t in known_captions for w in WORD.findall(t.lower())})
    known = set(vocab)
    unknown = sorted({w for t in taught for w in WORD.findall(t.lower()) if w not in known})
    if not unknown or not vocab:
        return []
    sims = embed(unknown) @ embed(vocab).T  # (U, V) cosine: unit embeddings
    choices = {}
    for i, word in enumerate(unknown):
        order = sims[i].argsort(descending=True).tolist()
        choices[word] = [vocab[j] for j in order if _ending(vocab[j]) == _ending(word)][:nearest] or [vocab[order[0]]]
    out = []
    for caption in taught:
        current, target = caption, embed([caption])
        for word in dict.fromkeys(w for w in WORD.findall(caption.lower()) if w in choices):
            options = [re.sub(rf"(?<![\w'-]){re.escape(word)}(?![\w'-])", c, current, flags=re.IGNORECASE)
                       for c in choices[word]]
            current = options[int((embed(options) @ target.T).argmax())]
        if current.lower() != caption.lower():
            out.append(current)
    return list(dict.fromkeys(out))


class _Run:
    """The work folder: the log and the resumable state (stage, step, LoRA weights, optimiser)."""

    def __init__(self, work: Path, fingerprint: str, resume: bool):
        self.work, self.fingerprint = work, fingerprint
        work.mkdir(parents=True, exist_ok=True)
        self.state = None
        if resume:
            path = work / STATE_FILE
            if not path.is_file():
                raise SMFError(f"nothing to resume in {work} (no {STATE_FILE}); start without --resume")
            self.state = torch.load(path, map_location="cpu", weights_only=True)
            if self.state.get("fingerprint") != fingerprint:
                raise SMFError(f"cannot resume {work}: it was started with other clips, captions, base model or "
                               "settings; start again without --resume")
        elif (work / "log.csv").exists():
            (work / "log.csv").unlink()
        if not (work / "log.csv").exists():
            (work / "log.csv").write_text(LOG_HEADER + "\n")
        self.seconds = float(self.state.get("seconds", 0.0)) if self.state else 0.0

    def save(self, **state) -> None:
        from ..core.io import atomic_path

        with atomic_path(self.work / STATE_FILE) as tmp:
            torch.save({"fingerprint": self.fingerprint, **state}, tmp)

    def log(self, rows: list[list]) -> None:
        with open(self.work / "log.csv", "a", newline="") as f:
            csv.writer(f).writerows(rows)


def _fingerprint(clips: list[Clip], base: dict[str, str], cfg: AdaptConfig) -> str:
    import hashlib

    h = hashlib.sha256(json.dumps([base, cfg.to_dict(), [(c.file, c.captions) for c in clips]]).encode())
    for c in clips:
        h.update(np.ascontiguousarray(c.features, dtype=np.float32).tobytes())
    return h.hexdigest()


def adapt(base: str | Path | None, clips: list[Clip], out: str | Path, cfg: AdaptConfig = AdaptConfig(), *,
          name: str, licence: str, work: str | Path | None = None, resume: bool = False, progress: bool = True,
          stop_after: tuple[int, int] | None = None, source: str = "") -> Adapter | None:
    """Adapt the model folder ``base`` (None: the shipped model) to ``clips``; writes the adapter file ``out``
    and returns it. ``work``: the resumable work folder (default ``<out>.work``). ``stop_after`` (stage, step)
    ends the run there as if interrupted right after a checkpoint (for tests)."""
    with no_fast_path():  # the wrapped models' text layers through their LoRA wrappers, in every mode
        return _adapt(base, clips, out, cfg, name=name, licence=licence, work=work, resume=resume, progress=progress,
                      stop_after=stop_after, source=source)


def said_of(clip: Clip, cfg: AdaptConfig) -> tuple[str, ...]:
    """What a clip is taught as: its captions, then each said ``cfg.paraphrases`` other ways from the lexicon
    (:func:`~stablemofusion.data.captions.paraphrases`, seeded by the clip; none without a lexicon)."""
    if not cfg.lexicon:
        return clip.captions
    other = [p for cap in clip.captions
             for p in paraphrases(cap, cfg.paraphrases, seed=f"{cfg.seed}|{clip.file}", lexicon=cfg.lexicon)]
    return tuple(dict.fromkeys(clip.captions + tuple(other)))


def _adapt(base, clips, out, cfg, *, name, licence, work, resume, progress, stop_after, source) -> Adapter | None:
    from accelerate import Accelerator
    from tqdm import tqdm

    from ..diffusion.distil import student_sample, teacher_sample
    from ..diffusion.schedule import make_train_scheduler
    from ..diffusion.solvers import solver_table
    from ..diffusion.train import masked_mse
    from ..core.limits import STUDENT_SAMPLER
    from ..core.folders import model_folder
    from ..pipelines.motion_pipeline import MotionPipeline

    # 1. check inputs, load the base (student and teacher), fingerprint the run
    cfg.check()
    if not clips:
        raise SMFError("no clips to adapt to")
    out = Path(out)
    work = Path(work) if work is not None else out.with_name(out.name + ".work")
    folder = model_folder(base)
    accelerator = Accelerator(cpu=not torch.cuda.is_available())
    device = accelerator.device
    student_pipe = MotionPipeline.from_pretrained(folder, backend="torch", device="cpu")
    if not student_pipe.student:
        raise SMFError(f"{folder} is not a distilled student with a teacher; adapt the model folder the default "
                       "path runs (a student with its teacher/)")
    teacher_pipe = MotionPipeline.from_pretrained(folder, backend="torch", teacher=True, device="cpu")
    hashes = {"student": weights_hash(folder), "teacher": weights_hash(model_folder(folder, teacher=True))}
    run = _Run(work, _fingerprint(clips, hashes, cfg), resume)
    state = run.state or {"stage": 1, "step": 0}
    t_start = time.perf_counter() - run.seconds
    lo, hi = student_pipe.min_frames, student_pipe.max_frames
    guidance = student_pipe.settings().guidance_scale  # what the default path samples with
    teacher_guidance = teacher_pipe.settings().guidance_scale

    # 2. prepare: the clips normalised as the models were trained, the taught captions, the replay set
    mean, std = torch.as_tensor(teacher_pipe.mean), torch.as_tensor(teacher_pipe.std)
    motions = [(torch.from_numpy(c.features).float() - mean) / std for c in clips]
    taught = sorted({cap for c in clips for cap in c.captions})
    said = [said_of(c, cfg) for c in clips]
    other_ways = sorted({cap for s in said for cap in s} - set(taught))
    text = student_pipe.text_cache
    rows: dict[str, torch.Tensor] = {}  # caption -> its frozen token states, encoded once in a fixed order

    def encode(captions: list[str]) -> None:
        """Encode captions not seen yet, in batches of a fixed order (a resumed run encodes them alike)."""
        new = list(dict.fromkeys(c for c in captions if c not in rows))
        for a in range(0, len(new), 64):
            tokens, tmask = text.get_or_compute(new[a:a + 64])
            for i, c in enumerate(new[a:a + 64]):
                rows[c] = tokens[i, :int(tmask[i].sum())].float().cpu()

    def tokens_of(captions: list[str]):
        from ..text.cache import pad_rows

        return pad_rows([rows[c] for c in captions], next(iter(rows.values())).shape[-1], device)

    def embed(texts: list[str]) -> torch.Tensor:
        from ..text.frozen import sentence_embedding

        tokens, tmask = text.get_or_compute(list(texts))
        return sentence_embedding(tokens.float().cpu(), tmask.cpu())

    known = student_pipe.known_actions.actions if student_pipe.known_actions is not None else {}
    # only the lexicon's actions the base knows: those it never learned would replay its failures at them
    learned = known or None
    candidates = lexicon_replay(cfg.lexicon, actions=learned) if cfg.lexicon \
        else [(a, e) for a, ex in known.items() for e in ex]
    retaught = retaught_actions(known, taught, embed)
    replay = replay_prompts(candidates, retaught, cfg.replay_prompts) if cfg.replay > 0 else []
    contrast = []  # the taught captions in the base's words (contrast_captions), several samples of each
    checks = student_pipe.known_actions.check_many(taught) if student_pipe.known_actions is not None else []
    in_domain = float(np.mean([not c.out_of_domain for c in checks])) if checks else 1.0
    if replay and cfg.contrast and (in_domain >= CONTRAST_IN_DOMAIN or not cfg.contrast_auto):
        wider = [text for _, text in lexicon_replay(cfg.lexicon, CONTRAST_PER_PAIR, actions=learned)] \
            if cfg.lexicon else []
        wider += [e for ex in known.values() for e in ex]
        contrast = contrast_captions(taught, wider, embed)
        if retaught:  # none that names an action taught anew
            contrast = [c for c, a in zip(contrast, named_actions(known, contrast, embed)) if a not in retaught]
        contrast *= cfg.contrast
    replay = contrast + replay
    encode(taught + other_ways + replay)
    replay_frames = [_frames(round(s * student_pipe.fps), lo, hi) for s in student_pipe.predict_seconds(replay)] \
        if replay and student_pipe.length_estimator is not None else [_frames(80, lo, hi)] * len(replay)
    replay_motion = []
    for a in range(0, len(replay), cfg.batch_size):  # the base teacher's own samples (its sampler and guidance)
        raw = teacher_pipe.denoise(replay[a:a + cfg.batch_size], replay_frames[a:a + cfg.batch_size],
                                   seed=[_mix(cfg.seed, 3, a + i) % SEED_RANGE for i in range(len(replay[a:a + cfg.batch_size]))])
        replay_motion += [(raw[i, :n] - mean) / std for i, n in enumerate(replay_frames[a:a + cfg.batch_size])]
    if cfg.replay > 0 and not replay:
        cfg = replace(cfg, replay=0.0)  # a base without known actions: nothing to replay
    n_replay = int(round(cfg.batch_size * cfg.replay))
    teacher = teacher_pipe.model.float().to(device)
    student = student_pipe.model.float().to(device)
    lora = LoraConfig(cfg.rank, cfg.alpha, text=cfg.text_layers)
    torch.manual_seed(cfg.seed)  # the LoRA A matrices' initial weights
    add_lora(teacher, lora)
    add_lora(student, lora)
    if "teacher" in state:
        load_lora_state(teacher, state["teacher"])
    if "student" in state:
        load_lora_state(student, state["student"])
    schedule = teacher_pipe.config.schedule
    T = schedule.num_train_timesteps
    noise_sched = make_train_scheduler(schedule)
    losses: dict[int, list[float]] = {1: [], 2: []}

    def train_stage(stage: int, model: torch.nn.Module, steps: int, lr: float, batch: Callable) -> None:
        params = [p for p in model.parameters() if p.requires_grad]
        optimizer = torch.optim.AdamW(params, lr=lr, weight_decay=0.0)
        start = 0
        if state["stage"] == stage and "optimizer" in state:
            optimizer.load_state_dict(state["optimizer"])
            start = int(state["step"])
        elif state["stage"] > stage:
            return
        wrapped, optimizer = accelerator.prepare(model, optimizer)
        end = steps if stop_after is None or stop_after[0] != stage else min(steps, stop_after[1])
        rows = []
        for step in tqdm(range(start, end), initial=start, total=steps, desc=f"adapt {stage}/2 "
                         f"{'teacher' if stage == 1 else 'student'}", unit="step", disable=not progress):
            lr_now = lr * min(1.0, (step + 1) / 20) * 0.5 * (1 + math.cos(math.pi * step / max(steps, 1)))
            for group in optimizer.param_groups:
                group["lr"] = lr_now
            g = torch.Generator().manual_seed(_mix(cfg.seed, stage, step))
            torch.manual_seed(_mix(cfg.seed, stage, step, 1))  # dropout inside the model
            wrapped.train(stage == 1)
            loss = batch(wrapped, g)
            accelerator.backward(loss)
            accelerator.clip_grad_norm_(params, cfg.grad_clip)
            optimizer.step()
            optimizer.zero_grad(set_to_none=True)
            value = loss.item()
            if not math.isfinite(value):
                raise SMFError(f"adapting diverged (stage {stage}, step {step}): loss is {value}; try a lower "
                               "learning rate")
            losses[stage].append(value)
            rows.append([stage, step + 1, f"{value:.6f}", f"{lr_now:.3e}", f"{time.perf_counter() - t_start:.2f}"])
            if (step + 1) % cfg.checkpoint_every == 0 or step + 1 == end:
                run.log(rows)
                rows = []
                done = step + 1 == steps
                run.save(stage=stage + 1 if done else stage, step=0 if done else step + 1,
                         teacher=lora_state(teacher), student=lora_state(student),
                         **({} if done else {"optimizer": optimizer.state_dict()}),
                         seconds=time.perf_counter() - t_start)
        model.eval()
        if end < steps:
            raise _Stopped

    # 3. stage 1: the teacher's LoRA on the clips (diffusion loss), a share ``replay`` of each batch replayed
    def teacher_batch(model, g: torch.Generator) -> torch.Tensor:
        items, captions = [], []
        for _ in range(cfg.batch_size - n_replay):
            i = int(torch.randint(len(motions), (), generator=g))
            m, caps = motions[i], said[i]
            n = _frames(int(torch.randint(lo, min(len(m), hi) + 1, (), generator=g)), lo, hi)
            s = int(torch.randint(0, len(m) - n + 1, (), generator=g))
            items.append(m[s:s + n])
            captions.append(caps[int(torch.randint(len(caps), (), generator=g))])
        for _ in range(n_replay):
            j = int(torch.randint(len(replay), (), generator=g))
            items.append(replay_motion[j])
            captions.append(replay[j])
        x0, mask = _pad(items)
        t = torch.randint(0, T, (len(items),), generator=g)
        noise = torch.randn(x0.shape, generator=g)
        drop = torch.rand(len(items), generator=g) < cfg.cond_drop
        x_t = noise_sched.add_noise(x0, noise, t)
        tokens, tmask = tokens_of(captions)
        pred = model(x_t.to(device), t.to(device), tokens, tmask, drop.to(device), mask.to(device))
        return masked_mse(pred.float(), x0.to(device), mask.to(device))

    try:
        train_stage(1, teacher, cfg.teacher_steps, cfg.teacher_lr, teacher_batch)

        # 4. stage 2: the student's targets (adapted teacher on the taught captions, base student on the replay)
        distilled = student_pipe.config.distil  # the teacher's sampler the student was distilled from
        teacher_table = solver_table(distilled.teacher_sampler, distilled.teacher_steps, schedule).to(device)
        steps_s = distilled.sample_steps
        student_table = solver_table(STUDENT_SAMPLER, steps_s, schedule).to(device)
        g = torch.Generator().manual_seed(_mix(cfg.seed, 4))
        order = torch.randperm(len(clips), generator=g).tolist()
        new_items = [(order[k % len(clips)], _frames(clips[order[k % len(clips)]].frames, lo, hi))
                     for k in range(cfg.pool)]
        pool = {"taught": [], "replay": []}

        def targets(captions, frames, sample) -> list[tuple[str, torch.Tensor, torch.Tensor]]:
            out = []
            for a in range(0, len(captions), cfg.batch_size):
                caps, ns = captions[a:a + cfg.batch_size], frames[a:a + cfg.batch_size]
                mask = torch.zeros(len(caps), max(ns), dtype=torch.bool)
                for i, n in enumerate(ns):
                    mask[i, :n] = True
                eps = torch.randn(mask.shape + (motions[0].shape[-1],), generator=g) * mask[..., None]
                tokens, tmask = tokens_of(caps)
                with torch.no_grad():
                    x = sample(eps.to(device), tokens, tmask, mask.to(device)).float().cpu()
                out += [(c, eps[i, :n], x[i, :n]) for i, (c, n) in enumerate(zip(caps, ns))]
            return out

        def teacher_target(eps, tokens, tmask, mask):
            drop = torch.zeros(len(eps), dtype=torch.bool, device=device)
            w = torch.full((len(eps),), guidance if cfg.target_guidance is None else cfg.target_guidance, device=device)
            return teacher_sample(teacher, eps, tokens, tmask, drop, mask, w, teacher_table, cfg.target_rescale)

        def student_out(model, eps, tokens, tmask, mask):
            drop = torch.zeros(len(eps), dtype=torch.bool, device=device)
            w = torch.full((len(eps),), guidance, device=device)
            step_noise = torch.zeros((steps_s,) + tuple(eps.shape), device=device)
            return student_sample(model, eps, tokens, tmask, drop, mask, w, student_table, step_noise)

        caps = [said[i][k // len(clips) % len(said[i])] for k, (i, _) in enumerate(new_items)]
        pool["taught"] = targets(caps, [n for _, n in new_items], teacher_target)
        if n_replay:
            picks = [k * len(replay) // cfg.pool if len(replay) > cfg.pool else k % len(replay) for k in range(cfg.pool)]
            reps, reps_frames = [replay[k] for k in picks], [replay_frames[k] for k in picks]
            # the base student's own outputs: its LoRA updates off (a resumed run has trained some already)
            saved = lora_state(student)
            load_lora_state(student, {k: torch.zeros_like(v) for k, v in saved.items()})
            pool["replay"] = targets(reps, reps_frames, lambda *a: student_out(student, *a))
            load_lora_state(student, saved)

        def student_batch(model, g: torch.Generator) -> torch.Tensor:
            picks = [pool["taught"][int(torch.randint(cfg.pool, (), generator=g))]
                     for _ in range(cfg.batch_size - n_replay)]
            picks += [pool["replay"][int(torch.randint(cfg.pool, (), generator=g))] for _ in range(n_replay)]
            eps, mask = _pad([p[1] for p in picks])
            target, _ = _pad([p[2] for p in picks])
            tokens, tmask = tokens_of([p[0] for p in picks])
            pred = student_out(model, eps.to(device), tokens, tmask, mask.to(device))
            return masked_mse(pred.float(), target.to(device), mask.to(device))

        train_stage(2, student, cfg.student_steps, cfg.student_lr, student_batch)
    except _Stopped:
        return None

    # 5. the adapter file
    seconds = time.perf_counter() - t_start
    info = AdapterInfo(name=name, actions={name: taught + other_ways},
                       clips=[(c.file, cap) for c in clips for cap in c.captions],
                       licence=licence, base=hashes, lora=lora, guidance=guidance,
                       training={"config": cfg.to_dict(), "clips": len(clips),
                                 "motion_seconds": round(sum(c.frames for c in clips) / student_pipe.fps, 1),
                                 "captions_from": source, "replay_prompts": len(replay) - len(contrast),
                                 "contrast_prompts": len(set(contrast)), "paraphrased": len(other_ways),
                                 "taught_in_domain": round(in_domain, 3),
                                 "not_replayed": sorted(retaught),
                                 "teacher_loss": _ends(losses[1]), "student_loss": _ends(losses[2]),
                                 "seconds": round(seconds, 1), "teacher_guidance": teacher_guidance})
    adapter = Adapter(info, {"student": lora_state(student), "teacher": lora_state(teacher)})
    adapter.save(out)
    return adapter


class _Stopped(Exception):
    """The run was stopped at ``stop_after`` (a checkpoint is saved)."""


def _ends(values: list[float], n: int = 20) -> list[float]:
    """Mean of the first and of the last ``n`` losses of this run (empty when it ran no step)."""
    if not values:
        return []
    return [round(float(np.mean(values[:n])), 5), round(float(np.mean(values[-n:])), 5)]


__all__ = ["AdaptConfig", "adapt", "contrast_captions", "lexicon_replay", "replay_prompts", "retaught_actions", "said_of"]
