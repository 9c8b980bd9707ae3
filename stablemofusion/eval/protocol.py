"""The T2M evaluation protocol over a corpus's test split.

Per replication ``r`` (default 20): the test items are drawn with crops and captions seeded by (seed, r)
(lengths are multiples of 4, as the official loader crops them), shuffled, and cut to whole batches of 32.
For each item a motion is generated from its caption at its length; the evaluator embeds the generated and
the real motions and the captions. Metrics per replication: FID against the test set's reference statistics
(a separate draw of the test crops), R-precision top-1/2/3 and matching distance in batches of 32,
diversity over 300 pairs, multimodality over ``mm_captions`` captions x ``mm_repeats`` samples (10 pairs each).
Reported as mean +- 1.96 std / sqrt(N) over the replications, with a "Real motion" row computed the same way.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from ..data.dataset import MotionTextDataset
from ..core.errors import SMFError
from ..motion.features import joints_from_features
from .metrics import activation_stats, diversity, frechet_distance, mean_ci, multimodality, r_precision

REFERENCE_EPOCH = 1_000_000  # the crop draw used for the reference statistics (never a replication's)
METRICS = ("fid", "top1", "top2", "top3", "matching", "diversity", "multimodality")


@dataclass
class EvalConfig:
    """Protocol settings (saved with every result)."""

    replications: int = 20
    batch_size: int = 32  # R-precision batch
    diversity_times: int = 300
    mm_captions: int = 100
    mm_repeats: int = 30
    mm_times: int = 10
    sampler: str | None = None  # None: the model's (a distilled student's own)
    steps: int | None = None  # None: the model's
    guidance_scale: float | None = None  # None: the model's
    footskate: str = "off"
    gen_batch: int = 32
    max_items: int | None = None  # use only this many test items per replication (ablations)
    seed: int = 0
    split: str = "test"
    extra: dict = field(default_factory=dict)

    @classmethod
    def quick(cls, **kw) -> "EvalConfig":
        """3 replications and 10 samples per multimodality caption: minutes, not hours, on a CPU."""
        return cls(**{"replications": 3, "mm_repeats": 12, **kw})

    def for_pipeline(self, pipe) -> "EvalConfig":
        """This config with ``pipe``'s model's guidance, steps and sampler where it leaves them None."""
        from ..core.settings import Settings

        s = pipe.settings(Settings(guidance_scale=self.guidance_scale, steps=self.steps, sampler=self.sampler))
        return replace(self, guidance_scale=s.guidance_scale, steps=s.steps, sampler=s.sampler)


@dataclass
class Items:
    """One replication's test draw: captions, lengths (frames), raw real features (list of (n, D))."""

    captions: list[str]
    lengths: list[int]
    real: list[np.ndarray]
    tokens: list[list[str]]
    ids: list[str] = field(default_factory=list)


def items_per_draw(n: int, batch_size: int, max_items: int | None) -> int:
    """Items one replication uses: all (or ``max_items``) cut to whole batches."""
    return (n if max_items is None else min(n, int(max_items))) // batch_size * batch_size


def draw_items(ds: MotionTextDataset, epoch: int, seed: int, batch_size: int, max_items: int | None) -> Items:
    """Test items of one replication, shuffled and cut to whole batches (the T2M loader drops the last)."""
    ds.set_epoch(epoch)
    order = np.random.default_rng([seed, epoch]).permutation(len(ds))
    n = items_per_draw(len(ds), batch_size, max_items)
    if n == 0:
        raise SMFError(f"the {ds.split} split has {len(ds)} usable items: fewer than one batch of {batch_size}")
    caps, lens, real, toks, ids = [], [], [], [], []
    for i in order[:n]:
        it = ds[int(i)]
        k = it["length"]
        ids.append(it["id"])
        caps.append(it["caption"])
        toks.append(it["tokens"])
        lens.append(k)
        real.append(ds.denormalize(it["motion"][:k].numpy()))
    return Items(caps, lens, real, toks, ids)


def _pad(feats: list[np.ndarray]) -> torch.Tensor:
    T = max(len(f) for f in feats)
    out = torch.zeros(len(feats), T, feats[0].shape[-1])
    for i, f in enumerate(feats):
        out[i, :len(f)] = torch.as_tensor(f)
    return out


class EmbeddingModel:
    """Evaluator plus the frozen text model's cache: embeds raw features and captions into numpy arrays."""

    def __init__(self, evaluator, text_cache, batch_size: int = 128):
        self.evaluator, self.text_cache, self.batch_size = evaluator.eval(), text_cache, batch_size

    @torch.no_grad()
    def motions(self, feats: list[np.ndarray]) -> np.ndarray:
        out = []
        for a in range(0, len(feats), self.batch_size):
            chunk = feats[a:a + self.batch_size]
            out.append(self.evaluator.embed_motion(_pad(chunk), [len(f) for f in chunk]).cpu().numpy())
        return np.concatenate(out)

    @torch.no_grad()
    def texts(self, captions: list[str], tokens: list[list[str]] | None = None) -> np.ndarray:
        """Caption embeddings (our evaluator reads the captions; ``tokens`` are for word/POS evaluators)."""
        out = []
        for a in range(0, len(captions), self.batch_size):
            tokens, mask = self.text_cache.get_or_compute(captions[a:a + self.batch_size])
            out.append(self.evaluator.embed_text(tokens.cpu(), mask.cpu()).cpu().numpy())
        return np.concatenate(out)


@dataclass
class Generated:
    """One generated motion: final ``features`` (n, D) in dataset units and ``joints`` (n, J, 3) metres,
    the rigid body they come from (None with the rigid stage off), and ``raw_joints`` (n, J, 3) decoded from
    the model's own features before the final stage."""

    features: np.ndarray
    joints: np.ndarray
    motion: object | None
    raw_joints: np.ndarray


def generate(pipe, captions: list[str], lengths: list[int], cfg: EvalConfig, seed: int,
             progress: Callable[[int], None] | None = None) -> list[Generated]:
    """One motion per caption at its length, batched by similar lengths: the pipeline's denoising, then its
    final stage (rigid fit, cleanup) on each."""
    order = np.argsort(lengths, kind="stable")
    out: list[Generated | None] = [None] * len(captions)
    for k, a in enumerate(range(0, len(order), cfg.gen_batch)):
        idx = order[a:a + cfg.gen_batch]
        raw = pipe.denoise([captions[i] for i in idx], [lengths[i] for i in idx], guidance_scale=cfg.guidance_scale,
                           steps=cfg.steps, sampler=cfg.sampler, seed=seed * 100_003 + k, footskate=cfg.footskate)
        for j, i in enumerate(idx):
            f0 = raw[j, :lengths[i]].numpy().astype(np.float64)
            f, motion = pipe.finish(f0, cfg.footskate)
            joints = motion.joints() if motion is not None else joints_from_features(f, pipe.skeleton)
            out[i] = Generated(f, joints, motion, joints_from_features(f0, pipe.skeleton))
        if progress:
            progress(len(idx))
    return out  # type: ignore[return-value]


def cleanup_change(before: list[np.ndarray], after: list[np.ndarray]) -> dict[str, float]:
    """Mean joint change and pose change (root-relative) in metres between two lists of joints (n, J, 3) of the
    same motions, after aligning each cleaned motion's heading and start to the original."""
    from ..footskate.cleanup import align_yaw_xz
    from ..footskate.metrics import joint_change, pose_change

    jc, pc = [], []
    for ja, b in zip(before, after):
        jb = align_yaw_xz(b, ja)
        jc.append(joint_change(ja, jb))
        pc.append(pose_change(ja, jb))
    return {"joint_change": float(np.mean(jc)), "pose_change": float(np.mean(pc))}


def body_metrics(joints: list[np.ndarray], motions: list | None, skeleton, fps: float) -> dict[str, float]:
    """Rigidity of a set of motions: mean bone-length std (m), worst-frame bone deviation (m; mean over motions
    and the largest), and the largest distance between a motion's joints ``.npy`` and its BVH read back (m)."""
    from ..motion.files import bvh_round_trip_error
    from ..motion.rigid import bone_length_deviation

    dev = [bone_length_deviation(j, skeleton) for j in joints]
    motions = motions if motions is not None else [None] * len(joints)
    bvh = [bvh_round_trip_error(j, m, skeleton, fps) for j, m in zip(joints, motions)]
    worst = [d["bone_worst"] for d in dev]
    return {"bone_std": float(np.mean([d["bone_std"] for d in dev])), "bone_worst": float(np.mean(worst)),
            "bone_worst_max": float(np.max(worst)), "npy_bvh_max": float(np.max(bvh))}


def row_metrics(emb_text: np.ndarray, emb_motion: np.ndarray, ref: tuple[np.ndarray, np.ndarray],
                cfg: EvalConfig, rng: np.random.Generator) -> dict[str, float]:
    """FID (vs reference stats), R-precision top-1/2/3, matching distance and diversity of one set."""
    top, match = r_precision(emb_text, emb_motion, cfg.batch_size)
    return {"fid": frechet_distance(*activation_stats(emb_motion), *ref), "top1": float(top[0]),
            "top2": float(top[1]), "top3": float(top[2]), "matching": match,
            "diversity": diversity(emb_motion, min(cfg.diversity_times, len(emb_motion) - 1), rng)}


def evaluate(pipe, embedder: EmbeddingModel, data: str | Path, cfg: EvalConfig, *, progress: bool = True,
             skate_metrics: Callable[[list[np.ndarray]], dict[str, float]] | None = None, body: bool = False,
             label_metrics: Callable[[list[str], list[np.ndarray]], dict[str, float]] | None = None) -> dict:
    """Run the protocol; returns {"config", "rows": {"Real motion": {...}, "Generated": {...}}, "runs"}.

    Each row maps a metric to (mean, 95% half-interval); ``runs`` keeps the per-replication values.
    ``skate_metrics`` (list of joints (n, J, 3) -> dict) adds footskate figures to both rows when given; with
    ``body`` both rows also get :func:`body_metrics` (bone lengths, joints .npy vs BVH); ``label_metrics``
    (motion ids, features -> dict) adds the label accuracy of a motion classifier to both rows."""
    if pipe is not None:  # record the guidance, steps and sampler the model samples with (its own by default)
        cfg = cfg.for_pipeline(pipe)
    if pipe is not None and cfg.mm_repeats <= cfg.mm_times:
        raise SMFError(f"mm_repeats ({cfg.mm_repeats}) must exceed mm_times ({cfg.mm_times})")
    ds = MotionTextDataset(data, cfg.split, seed=cfg.seed, max_frames=pipe.max_frames if pipe else None,
                           feat_bias=1.0)
    ref_items = draw_items(ds, REFERENCE_EPOCH, cfg.seed, 1, None)
    ref = activation_stats(embedder.motions(ref_items.real))
    runs: dict[str, list[dict]] = {"Real motion": [], "Generated": []}
    gen_seconds, gen_count = 0.0, 0
    n_items = items_per_draw(len(ds), cfg.batch_size, cfg.max_items)
    mm_n = min(cfg.mm_captions, n_items) if pipe is not None and cfg.mm_captions > 0 else 0
    total = cfg.replications * (n_items + mm_n * cfg.mm_repeats) if pipe is not None else 0
    bar = tqdm(total=total, desc="evaluate", unit="motion", disable=not progress or total == 0)
    for r in range(cfg.replications):
        rng = np.random.default_rng([cfg.seed, r, 7])
        items = draw_items(ds, r, cfg.seed, cfg.batch_size, cfg.max_items)
        text = embedder.texts(items.captions, items.tokens)
        real_row = row_metrics(text, embedder.motions(items.real), ref, cfg, rng)
        if skate_metrics or body:
            real_joints = [joints_from_features(f.astype(np.float64), ds.skeleton) for f in items.real]
        if skate_metrics:
            real_row.update(skate_metrics(real_joints))
        if label_metrics:
            real_row.update(label_metrics(items.ids, items.real))
        if body:
            real_row.update(body_metrics(real_joints, None, ds.skeleton, ds.skeleton.fps))
        runs["Real motion"].append(real_row)
        if pipe is None:
            continue
        t0 = time.perf_counter()
        gen = generate(pipe, items.captions, items.lengths, cfg, seed=cfg.seed * 1000 + r, progress=bar.update)
        gen_seconds += time.perf_counter() - t0
        gen_count += len(gen)
        row = row_metrics(text, embedder.motions([g.features for g in gen]), ref, cfg, rng)
        if skate_metrics:
            row.update(skate_metrics([g.joints for g in gen]))
        if label_metrics:
            row.update(label_metrics(items.ids, [g.features for g in gen]))
        if body:
            row.update(body_metrics([g.joints for g in gen], [g.motion for g in gen], pipe.skeleton, pipe.fps))
        # the same seeds without cleanup: how much did cleanup move the joints? (and everything after the
        # model: the rigid stage too, from the model's own decoded joints)
        base = gen if cfg.footskate == "off" else generate(
            pipe, items.captions, items.lengths, replace(cfg, footskate="off"), seed=cfg.seed * 1000 + r)
        if cfg.footskate != "off":
            row.update(cleanup_change([g.joints for g in base], [g.joints for g in gen]))
        row["model_change"] = cleanup_change([g.raw_joints for g in base], [g.joints for g in gen])["joint_change"]
        if mm_n:
            caps = items.captions[:mm_n]
            lens = items.lengths[:mm_n]
            mm_gen = generate(pipe, [c for c in caps for _ in range(cfg.mm_repeats)],
                              [n for n in lens for _ in range(cfg.mm_repeats)], cfg, seed=cfg.seed * 1000 + r + 500,
                              progress=bar.update)
            emb = embedder.motions([g.features for g in mm_gen]).reshape(mm_n, cfg.mm_repeats, -1)
            row["multimodality"] = multimodality(emb, cfg.mm_times, rng)
        runs["Generated"].append(row)
    bar.close()
    rows = {name: {k: mean_ci([run[k] for run in rs]) for k in rs[0]} for name, rs in runs.items() if rs}
    result = {"config": asdict(cfg), "items_per_replication": n_items, "rows": rows, "runs": runs}
    if gen_count:
        result["aits_seconds"] = gen_seconds / gen_count
    return result


def markdown_table(result: dict, title_col: str = "Method") -> str:
    """The rows of :func:`evaluate` as a markdown table (mean ± 95% half-interval)."""
    keys = [k for k in (*METRICS, *sorted({k for r in result["rows"].values() for k in r} - set(METRICS)))
            if any(k in r for r in result["rows"].values())]
    names = {"fid": "FID ↓", "top1": "R-prec top-1 ↑", "top2": "top-2 ↑", "top3": "top-3 ↑",
             "matching": "Matching ↓", "diversity": "Diversity →", "multimodality": "MModality ↑"}
    lines = ["| " + " | ".join([title_col, *[names.get(k, k) for k in keys]]) + " |",
             "|" + "---|" * (len(keys) + 1)]
    for name, row in result["rows"].items():
        cells = [f"{row[k][0]:.3f} ± {row[k][1]:.3f}" if k in row else "–" for k in keys]
        lines.append("| " + " | ".join([name, *cells]) + " |")
    return "\n".join(lines)


class T2MEmbedding(EmbeddingModel):
    """The original T2M evaluator (:mod:`.t2m_original`): it embeds word/POS tokens, not captions."""

    @torch.no_grad()
    def texts(self, captions: list[str], tokens: list[list[str]] | None = None) -> np.ndarray:
        if tokens is None or any(not t for t in tokens):
            raise SMFError("the original T2M evaluator needs word/POS tokens for every caption")
        return np.concatenate([self.evaluator.embed_tokens(tokens[a:a + self.batch_size]).cpu().numpy()
                               for a in range(0, len(tokens), self.batch_size)])


__all__ = ["EvalConfig", "Generated", "T2MEmbedding", "body_metrics", "evaluate", "draw_items", "generate", "row_metrics", "EmbeddingModel", "markdown_table"]
