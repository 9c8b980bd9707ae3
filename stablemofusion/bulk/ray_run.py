"""A bulk plan run on Ray: one actor per worker holds a pipeline and makes whole shards; the driver hands out the
shards still to make and counts them. A worker process that dies is started again by Ray and its shard made again
(a shard is written whole or not at all, and the same shard gives the same motions); a driver that dies leaves the
shards written so far, and the same command resumes from them."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

import pyarrow.compute as pc
import ray
from ray.util import ActorPool
from tqdm import tqdm

from .dataset import BulkPlan, make_shard, start, write_shard


@ray.remote(num_cpus=1, max_restarts=-1, max_task_retries=-1)
class ShardWorker:
    """One worker: a pipeline (made once by ``make_pipeline``) that makes shards and writes them into ``out``."""

    def __init__(self, make_pipeline: Callable[[], object], out: str):
        self.pipe = make_pipeline()
        self.out = Path(out)

    def pid(self) -> int:
        return os.getpid()

    def make(self, plan: BulkPlan, shard: int) -> tuple[int, int, int]:
        """Make and write ``shard``: (shard, motions, motions of prompts out of the model's domain)."""
        table = make_shard(self.pipe, plan, shard)
        write_shard(self.out, shard, table)
        return shard, table.num_rows, int(pc.sum(table.column("out_of_domain")).as_py() or 0)


def run(plan: BulkPlan, out: Path, make_pipeline: Callable[[], object], *, workers: int, address: str | None = None,
        progress: bool = True, on_started: Callable[[list], None] | None = None) -> dict:
    """Make the shards of ``plan`` not yet in ``out`` on ``workers`` Ray actors (a local cluster of ``workers``
    CPUs when ``address`` is None, else the cluster there). ``on_started(actors)`` is called once they are up.
    Returns counts: shards made now, shards found done, motions made now, and of them those whose prompt is unlike
    anything the model knows (``out_of_domain`` in the dataset)."""
    todo = start(out, plan)
    done_before = plan.shards - len(todo)
    if not todo:
        return {"shards": plan.shards, "made": 0, "found": done_before, "motions": 0, "out_of_domain": 0}
    if not ray.is_initialized():
        if address is None:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False, configure_logging=False)
        else:
            ray.init(address=address, include_dashboard=False, log_to_driver=False, configure_logging=False)
    actors = [ShardWorker.remote(make_pipeline, str(out)) for _ in range(min(workers, len(todo)))]
    ray.get([a.pid.remote() for a in actors])  # each has loaded its pipeline
    if on_started is not None:
        on_started(actors)
    motions = unknown = 0
    bar = tqdm(total=len(plan.prompts), initial=done_before * plan.shard_size, unit="motion", desc="bulk",
               disable=not progress)
    for _, count, odd in ActorPool(actors).map_unordered(lambda a, j: a.make.remote(plan, j), todo):
        motions += count
        unknown += odd
        bar.update(count)
    bar.close()
    for a in actors:
        ray.kill(a)
    return {"shards": plan.shards, "made": len(todo), "found": done_before, "motions": motions,
            "out_of_domain": unknown}


__all__ = ["ShardWorker", "run"]
