"""A bulk run's plan and its dataset: prompts cut into shards of whole batches, each shard one Parquet file written
atomically (complete or absent), beside a manifest that a resumed run must match.

A shard's motions are exactly those `smf generate --prompts FILE --seed S --batch-size B` makes: batch k of the
prompts (prompts k*B .. k*B + B - 1) is one pipeline call with seed S + k.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from .. import __version__
from ..core.errors import SMFError
from ..core.io import atomic_path, write_text

MANIFEST = "_manifest.json"  # a leading underscore: Parquet readers (pyarrow, datasets) skip it
FORMAT = 1  # bump when the columns change
JOINTS = 22
CONTACTS = pa.list_(pa.list_(pa.bool_(), 4))  # per frame, the foot joints the cleanup held (None without cleanup)


@dataclass(frozen=True)
class BulkPlan:
    """What a bulk run makes: ``prompts`` with ``seed`` and ``batch_size`` as `smf generate --prompts` uses them,
    ``shard_batches`` batches a shard; ``seconds`` each motion's length (None: predicted from its text);
    ``sampling`` the pipeline's keywords (guidance, steps, footskate, engine); ``model`` what made them."""

    prompts: tuple[str, ...]
    seed: int
    batch_size: int
    shard_batches: int
    seconds: float | None
    sampling: tuple[tuple[str, object], ...]
    model: str

    def __post_init__(self):
        if not self.prompts:
            raise SMFError("a bulk run needs at least one prompt")
        if self.batch_size < 1 or self.shard_batches < 1:
            raise SMFError(f"batch size and batches per shard are at least 1, got {self.batch_size} and "
                           f"{self.shard_batches}")

    @property
    def shard_size(self) -> int:
        return self.batch_size * self.shard_batches

    @property
    def shards(self) -> int:
        return -(-len(self.prompts) // self.shard_size)

    def batches(self, shard: int) -> list[tuple[int, range]]:
        """(batch number, prompt indices) of each batch of ``shard``."""
        first = shard * self.shard_batches
        out = []
        for k in range(first, first + self.shard_batches):
            indices = range(k * self.batch_size, min(len(self.prompts), (k + 1) * self.batch_size))
            if len(indices):
                out.append((k, indices))
        return out

    def manifest(self) -> dict:
        """What identifies the run (a resumed run must give the same): the prompts' hash, not the prompts."""
        text = "\n".join(self.prompts).encode("utf-8")
        fields = {k: v for k, v in asdict(self).items() if k != "prompts"}
        fields["sampling"] = dict(self.sampling)
        return {"format": FORMAT, "prompts": len(self.prompts), "prompts_sha256": hashlib.sha256(text).hexdigest(),
                "shards": self.shards, **fields}


def shard_path(out: Path, shard: int) -> Path:
    return Path(out) / f"shard-{shard:05d}.parquet"


def start(out: Path, plan: BulkPlan) -> list[int]:
    """Make ``out`` the plan's dataset folder: write its manifest, or check that the one there is this plan's (a
    resumed run). Returns the shards still to make (those whose file is absent)."""
    out = Path(out)
    manifest = plan.manifest()
    path = out / MANIFEST
    if path.is_file():
        try:
            have = json.loads(path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise SMFError(f"{path}: not a bulk run's manifest ({e})") from None
        if have != manifest:
            differ = sorted(k for k in set(have) | set(manifest) if have.get(k) != manifest.get(k))
            raise SMFError(f"{out} holds another run's dataset (it differs in {', '.join(differ)}); "
                           "give another --out, or the same prompts and settings to resume it")
    elif out.exists() and any(out.iterdir()):
        raise SMFError(f"{out} is not empty and holds no bulk run: give a new or empty folder")
    else:
        write_text(path, json.dumps(manifest, indent=1) + "\n")
    return [j for j in range(plan.shards) if not shard_path(out, j).is_file()]


def make_shard(generate: Callable[..., list], plan: BulkPlan, shard: int) -> pa.Table:
    """The motions of ``shard``: ``generate(prompts, seconds=, batch_size=, seed=, **sampling)`` (a pipeline's
    call) once per batch, as `smf generate --prompts` calls it."""
    rows = []
    for k, indices in plan.batches(shard):
        results = generate([plan.prompts[i] for i in indices], seconds=plan.seconds, batch_size=plan.batch_size,
                           seed=plan.seed + k, **dict(plan.sampling))
        rows += [(i, plan.seed + k, r) for i, r in zip(indices, results)]
    return motions_table(rows)


def motions_table(rows: Sequence[tuple[int, int, object]]) -> pa.Table:
    """One row per (prompt index, batch seed, result): the columns of docs/bulk.md."""
    frames = np.asarray([len(r.joints) for _, _, r in rows], dtype=np.int32)
    offsets = pa.array(np.concatenate([[0], np.cumsum(frames)]).astype(np.int32))
    flat = pa.array(np.concatenate([np.asarray(r.joints, np.float32).ravel() for _, _, r in rows]))
    joints = pa.ListArray.from_arrays(offsets, pa.FixedSizeListArray.from_arrays(
        pa.FixedSizeListArray.from_arrays(flat, 3), JOINTS))
    held = [r.contacts for _, _, r in rows]
    contacts = None
    if all(c is not None for c in held):
        contacts = pa.ListArray.from_arrays(offsets, pa.FixedSizeListArray.from_arrays(
            pa.array(np.concatenate([np.asarray(c, bool).ravel() for c in held])), 4))
    domain = [r.domain for _, _, r in rows]
    columns = {
        "index": pa.array([i for i, _, _ in rows], pa.int64()),
        "prompt": pa.array([r.prompt for _, _, r in rows], pa.string()),
        "seed": pa.array([s for _, s, _ in rows], pa.int64()),
        "fps": pa.array([r.fps for _, _, r in rows], pa.float32()),
        "frames": pa.array(frames),
        "joints": joints,
        "contacts": contacts if contacts is not None else pa.nulls(len(rows), CONTACTS),
        "similarity": pa.array([None if d is None else d.similarity for d in domain], pa.float32()),
        "out_of_domain": pa.array([None if d is None else d.out_of_domain for d in domain], pa.bool_()),
    }
    return pa.table(columns)


def write_shard(out: Path, shard: int, table: pa.Table) -> Path:
    """Write ``shard``'s table whole, or nothing (a killed writer leaves no partial shard)."""
    path = shard_path(out, shard)
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)
    return path


def read_dataset(out: Path) -> pa.Table:
    """Every shard of a bulk run's folder as one table, sorted by prompt index."""
    files = sorted(Path(out).glob("shard-*.parquet"))
    if not files:
        raise SMFError(f"{out} holds no shards")
    return pa.concat_tables([pq.read_table(f) for f in files]).sort_by("index")


def joints_of(table: pa.Table, row: int) -> np.ndarray:
    """(T, 22, 3) float32 joints of one row."""
    return np.asarray(table.column("joints")[row].as_py(), dtype=np.float32)


__all__ = ["BulkPlan", "MANIFEST", "joints_of", "make_shard", "motions_table", "read_dataset", "shard_path", "start",
           "write_shard"]
