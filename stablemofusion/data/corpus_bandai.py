"""Build a text-motion corpus in the official HumanML3D layout from the Bandai-Namco BVH datasets.

Every clip is retargeted onto the 22-joint layout (20 fps), cut into segments of at most 196 feature
frames (the official loader drops longer motions), turned into features, mirrored (``M`` ids, with
mirrored words) and captioned from its content and style labels. The split keeps a clip, its segments
and their mirrors together and puts every content x style pair in train.
"""

from __future__ import annotations

import csv
import io
import json
import math
import multiprocessing
import random
import tarfile
import zlib
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..core.errors import SMFError
from ..core.io import save_npy, write_text
from ..motion.features import bone_lengths, features_from_joints, joints_from_features, mirror_joints
from ..motion.retarget import JointMap, retarget_bvh
from ..motion.skeleton import HUMANML3D
from .captions import captions_for, mirror_caption, mirror_tokens
from .layout import CaptionLine, format_text_line, mean_std

MAX_FRAMES = HUMANML3D.max_frames  # feature frames per motion (official max length)
MIN_FRAMES = HUMANML3D.min_frames
DATASET_DIRS = {1: "Bandai-Namco-Research-Motiondataset-1", 2: "Bandai-Namco-Research-Motiondataset-2"}


@dataclass(frozen=True)
class Clip:
    """One source BVH file and its labels."""

    dataset: int
    path: Path
    content: str
    style: str

    @property
    def name(self) -> str:
        return self.path.stem


def extract_archive(archive: Path, cache: Path) -> Path:
    """Unpack the Bandai-Namco ``.tar.xz`` into ``cache`` once (a marker file makes it idempotent)."""
    marker = cache / ".extracted"
    if marker.exists():
        return cache / "dataset"
    if not archive.is_file():
        raise SMFError(f"no such archive: {archive}")
    cache.mkdir(parents=True, exist_ok=True)
    try:
        with tarfile.open(archive, "r:*") as tar:
            members = tar.getmembers()
            for m in tqdm(members, desc="extract", unit="file", leave=False):
                tar.extract(m, cache, filter="data")
    except (tarfile.TarError, EOFError, OSError) as e:
        raise SMFError(f"{archive}: cannot unpack ({e})") from None
    marker.write_text("ok\n")
    return cache / "dataset"


def find_clips(root: Path) -> list[Clip]:
    """All labelled clips under the unpacked ``dataset/`` folder, sorted by dataset and file name."""
    clips = []
    for ds, sub in DATASET_DIRS.items():
        base = root / sub
        if not base.is_dir():
            raise SMFError(f"missing folder {base} in the Bandai-Namco source")
        labels = {}
        for kind in ("content", "style"):
            f = base / "cfg" / f"{kind}_label.txt"
            if not f.is_file():
                raise SMFError(f"missing label file {f}")
            labels[kind] = [ln.strip().split("_", 1)[-1] for ln in f.read_text().splitlines() if ln.strip()]
        for bvh in sorted((base / "data").glob("*.bvh")):
            meta = bvh.with_suffix(".json")
            try:
                lab = json.loads(meta.read_text())
                clips.append(Clip(ds, bvh, labels["content"][lab["content"]], labels["style"][lab["style"]]))
            except (OSError, ValueError, KeyError, IndexError) as e:
                raise SMFError(f"{meta}: unreadable label file ({e.__class__.__name__})") from None
    return clips


def segment_bounds(frames: int, max_len: int = MAX_FRAMES) -> list[tuple[int, int]]:
    """Split ``frames`` feature frames into equal segments of at most ``max_len``: [(start, stop), ...]."""
    k = max(1, math.ceil(frames / max_len))
    edges = np.linspace(0, frames, k + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def _texts(captions: list[tuple[str, list[str]]]) -> str:
    return "".join(format_text_line(CaptionLine(c, t, 0.0, 0.0)) + "\n" for c, t in captions)


def process_clip(clip: Clip, first_id: int, out: Path, n_captions: int, first_frame: str = "official") -> dict:
    """Retarget, segment, featurise (``first_frame``: see :func:`features_from_joints`), mirror and caption one
    clip; write its files; return its record."""
    joints = retarget_bvh(clip.path, JointMap.builtin("bandai-namco"))
    lengths = bone_lengths(joints)[:, 1:]
    record = {"clip": clip.name, "dataset": clip.dataset, "content": clip.content, "style": clip.style,
              "source_frames_20fps": len(joints), "bone_length_std_cm": float(lengths.std(0).max() * 100),
              "first_frame": first_frame, "segments": []}
    speed = np.linalg.norm(np.diff(joints[:, 0, [0, 2]], axis=0), axis=-1).mean() * 20.0
    record["mean_root_speed_m_s"] = float(speed)
    for k, (a, b) in enumerate(segment_bounds(len(joints) - 1)):
        # short clips are kept (as HumanML3D keeps them); the loader's length filter decides their use
        mid = f"{first_id + k:06d}"
        seg = joints[a:b + 1]
        caps = captions_for(clip.content, clip.style, n=n_captions, seed=mid)
        for prefix, src, texts in (
            ("", seg, caps),
            ("M", mirror_joints(seg), [(mirror_caption(c), mirror_tokens(t)) for c, t in caps]),
        ):
            feats = features_from_joints(src, first_frame=first_frame)
            save_npy(out / "new_joint_vecs" / f"{prefix}{mid}.npy", feats.astype(np.float32))
            save_npy(out / "new_joints" / f"{prefix}{mid}.npy", joints_from_features(feats).astype(np.float32))
            write_text(out / "texts" / f"{prefix}{mid}.txt", _texts(texts))
        record["segments"].append({"id": mid, "start": a, "frames": b - a, "captions": len(caps)})
    return record


def _work(args) -> dict:
    clip, first_id, out, n_captions, first_frame = args
    rec = process_clip(clip, first_id, out, n_captions, first_frame)
    write_text(out / ".work" / f"{clip.name}.json", json.dumps(rec))
    return rec


def assign_splits(records: list[dict], seed: int = 0) -> dict[str, list[str]]:
    """Deterministic train/val/test split by source clip (about 80/5/15 within each content x style pair);
    every pair keeps at least one clip in train. Returns split -> ids (mirrors included)."""
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in records:
        groups[(r["dataset"], r["content"], r["style"])].append(r)
    splits: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    for key in sorted(groups):
        clips = sorted(groups[key], key=lambda r: r["clip"])
        random.Random(zlib.crc32(f"{seed}:{key}".encode())).shuffle(clips)
        # the pair's longest clip goes to train (last), so the pair stays trainable at the 40-frame minimum
        longest = max(clips, key=lambda r: (max((s["frames"] for s in r["segments"]), default=0), r["clip"]))
        clips = [r for r in clips if r is not longest] + [longest]
        n = len(clips)
        n_test = 0 if n < 2 else max(1, round(0.15 * n))
        n_val = round(0.05 * n) if n - n_test - round(0.05 * n) >= 1 else 0
        for i, r in enumerate(clips):
            split = "test" if i < n_test else "val" if i < n_test + n_val else "train"
            for s in r["segments"]:
                splits[split] += [s["id"], "M" + s["id"]]
    return {k: sorted(v) for k, v in splits.items()}


def build_corpus(source: Path, out: Path, *, cache: Path | None = None, workers: int = 2, limit: int | None = None,
                 n_captions: int = 16, seed: int = 0, first_frame: str = "official") -> dict:
    """Build the corpus at ``out`` from the archive (or an unpacked folder holding ``dataset/``).

    Idempotent: clips whose record exists in ``out/.work`` are not processed again. Returns the stats.
    """
    source, out = Path(source), Path(out)
    if source.is_dir():
        root = source / "dataset" if (source / "dataset").is_dir() else source
    else:
        root = extract_archive(source, Path(cache) if cache else out / ".source")
    clips = find_clips(root)
    if limit is not None:
        clips = _spread(clips, limit)
    first_ids, next_id = [], 0
    for c in clips:  # ids depend only on the clip order, so re-runs and partial runs agree
        first_ids.append(next_id)
        next_id += len(segment_bounds(_frames_20fps(c) - 1))
    todo, records = [], {}
    for c, fid in zip(clips, first_ids):
        done = out / ".work" / f"{c.name}.json"
        if done.exists():
            records[c.name] = json.loads(done.read_text())
            if records[c.name].get("first_frame", "official") != first_frame:
                raise SMFError(f"{out} was prepared with first_frame={records[c.name].get('first_frame', 'official')!r}; "
                               f"use another --out for {first_frame!r}")
        else:
            todo.append((c, fid, out, n_captions, first_frame))
    if todo and workers <= 1:
        for rec in tqdm(map(_work, todo), total=len(todo), desc="clips", unit="clip"):
            records[rec["clip"]] = rec
    elif todo:
        # spawn, not fork: forking a process whose torch/OpenMP threads are running can deadlock the child
        with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            for rec in tqdm(pool.map(_work, todo, chunksize=4), total=len(todo), desc="clips", unit="clip"):
                records[rec["clip"]] = rec
    ordered = [records[c.name] for c in clips]
    splits = assign_splits(ordered, seed)
    for name, ids in splits.items():
        write_text(out / f"{name}.txt", "".join(i + "\n" for i in ids))
    write_text(out / "all.txt", "".join(i + "\n" for i in sorted(sum(splits.values(), []))))
    train = [np.load(out / "new_joint_vecs" / f"{i}.npy") for i in splits["train"]]
    mean, std = mean_std(train, "humanml3d")
    save_npy(out / "Mean.npy", mean.astype(np.float32))
    save_npy(out / "Std.npy", std.astype(np.float32))
    _write_clips_csv(out / "clips.csv", ordered, splits)
    stats = corpus_stats(ordered, splits)
    write_text(out / "stats.json", json.dumps(stats, indent=2) + "\n")
    return stats


def _frames_20fps(clip: Clip) -> int:
    """Number of 20 fps frames a clip gives, from its BVH header (cheap: no motion parsing)."""
    with open(clip.path, "rb") as f:
        head = f.read(1 << 16).decode("utf-8", "replace")
    try:
        frames = int(head.split("Frames:")[1].split()[0])
        frame_time = float(head.split("Frame Time:")[1].split()[0])
    except (IndexError, ValueError):
        raise SMFError(f"{clip.path}: no 'Frames:'/'Frame Time:' header") from None
    return int(math.floor((frames - 1) * frame_time * 20.0 + 1e-6)) + 1


def _spread(clips: list[Clip], limit: int) -> list[Clip]:
    """A deterministic subset of ``limit`` clips spread over all labels (for quick runs and tests)."""
    by_label: dict[tuple, list[Clip]] = defaultdict(list)
    for c in clips:
        by_label[(c.dataset, c.content, c.style)].append(c)
    picked, rnd = [], 0
    while len(picked) < min(limit, len(clips)):
        for key in sorted(by_label):
            if rnd < len(by_label[key]) and len(picked) < limit:
                picked.append(by_label[key][rnd])
        rnd += 1
    return sorted(picked, key=lambda c: (c.dataset, c.name))


def _write_clips_csv(path: Path, records: list[dict], splits: dict[str, list[str]]) -> None:
    split_of = {i: s for s, ids in splits.items() for i in ids}
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["id", "clip", "dataset", "content", "style", "start_frame", "frames", "split"])
    for r in records:
        for s in r["segments"]:
            w.writerow([s["id"], r["clip"], r["dataset"], r["content"], r["style"], s["start"], s["frames"],
                        split_of[s["id"]]])
    write_text(path, buf.getvalue())


def corpus_stats(records: list[dict], splits: dict[str, list[str]]) -> dict:
    """Sanity figures: counts, hours, captions, bone-length constancy, speeds of walk/run/dash."""
    segs = [s for r in records for s in r["segments"]]
    train = set(splits["train"])
    frames = sum(s["frames"] for s in segs)
    speed: dict[str, list[float]] = defaultdict(list)
    for r in records:
        if r["content"] in ("walk", "run", "dash"):
            speed[r["content"]].append(r["mean_root_speed_m_s"])
    bone_std = [r["bone_length_std_cm"] for r in records]
    return {
        "lexicon": "bandai",  # captions come from assets/lexicons/bandai.json (training augmentation reads it)
        "clips": len(records),
        "motions": len(segs),
        "motions_with_mirrors": 2 * len(segs),
        "frames": frames,
        "hours": frames / 20.0 / 3600.0,
        "captions": 2 * sum(s["captions"] for s in segs),
        "split_sizes": {k: len(v) for k, v in splits.items()},
        "contents": len({r["content"] for r in records}),
        "content_style_pairs": len({(r["dataset"], r["content"], r["style"]) for r in records}),
        "motions_under_40_frames": sum(s["frames"] < MIN_FRAMES for s in segs),
        "content_style_pairs_trainable": len({(r["dataset"], r["content"], r["style"]) for r in records
                                              if any(s["frames"] >= MIN_FRAMES and s["id"] in train for s in
                                                     r["segments"])}),
        "bone_length_std_within_clip_cm": {"max": max(bone_std), "median": float(np.median(bone_std))},
        "mean_root_speed_m_s": {k: float(np.mean(v)) for k, v in sorted(speed.items())},
    }


def format_stats(stats: dict) -> str:
    """Human-readable summary of :func:`corpus_stats`."""
    sp = stats["mean_root_speed_m_s"]
    lines = [
        f"clips {stats['clips']}, motions {stats['motions']} (+{stats['motions']} mirrored), "
        f"frames {stats['frames']}, hours {stats['hours']:.2f}, captions {stats['captions']}",
        "splits " + ", ".join(f"{k} {v}" for k, v in stats["split_sizes"].items()),
        f"content x style pairs {stats['content_style_pairs']}, with a train motion of >= 40 frames "
        f"{stats['content_style_pairs_trainable']}; motions under 40 frames {stats['motions_under_40_frames']}",
        f"bone length std within a clip: max {stats['bone_length_std_within_clip_cm']['max']:.4f} cm, "
        f"median {stats['bone_length_std_within_clip_cm']['median']:.4f} cm",
        "mean root speed (m/s): " + ", ".join(f"{k} {v:.2f}" for k, v in sp.items()),
    ]
    if all(k in sp for k in ("walk", "run", "dash")):
        ok = sp["walk"] < sp["run"] < sp["dash"]
        lines.append(f"walk < run < dash: {'yes' if ok else 'NO'}")
    return "\n".join(lines)


__all__ = ["Clip", "build_corpus", "find_clips", "segment_bounds", "assign_splits", "corpus_stats", "format_stats"]
