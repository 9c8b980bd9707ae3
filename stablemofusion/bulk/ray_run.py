"""A bulk plan run on Ray: one actor per worker holds a pipeline and makes whole shards; the driver hands out the
shards still to make and counts them. A worker process that dies is started again by Ray and its shard made again
(a shard is written whole or not at all, and the same shard gives the same motions); a driver that dies leaves the
shards written so far, and the same command resumes from them."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Callable

import pyarrow.compute as pc
import ray
from ray.util import ActorPool
from tqdm import tqdm

from ..core.errors import SMFError
from .dataset import BulkPlan, make_shard, start, write_shard


RESTARTS = 3  # a worker process that dies is started again, and its shard tried again, this many times


@ray.remote(num_cpus=1, max_restarts=RESTARTS, max_task_retries=RESTARTS)
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


def run(plan: BulkPlan, out: Path, make_pipeline: Callable[[], object], *, workers: int | None = None,
        address: str | None = None, progress: bool = True, on_started: Callable[[list], None] | None = None) -> dict:
    """Make the shards of ``plan`` not yet in ``out`` on ``workers`` Ray actors (default: one per CPU of the
    cluster): a local cluster of this machine's CPUs when ``address`` is None, else the cluster there.
    ``on_started(actors)`` is called once they are up. Returns counts: shards made now, shards found done, motions
    made now, and of them those whose prompt is unlike anything the model knows (``out_of_domain`` in the
    dataset). A worker's failure (a model that does not load, a shard that fails every try) is one line."""
    todo = start(out, plan)
    done_before = plan.shards - len(todo)
    if not todo:
        return {"shards": plan.shards, "made": 0, "found": done_before, "motions": 0, "out_of_domain": 0}
    if not ray.is_initialized():
        local = {"num_cpus": workers or os.cpu_count() or 1} if address is None else {"address": address}
        ray.init(**local, include_dashboard=False, log_to_driver=False, configure_logging=False)
    workers = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
    actors = [ShardWorker.remote(make_pipeline, str(out)) for _ in range(min(workers, len(todo)))]
    motions = unknown = 0
    made_before = len(plan.prompts) - sum(len(i) for j in todo for _, i in plan.batches(j))
    bar = tqdm(total=len(plan.prompts), initial=made_before, unit="motion", desc="bulk", disable=not progress)
    shared = ray.put(plan)  # the prompts are sent to the cluster once, not with every shard
    try:
        ray.get([a.pid.remote() for a in actors])  # each has loaded its pipeline
        if on_started is not None:
            on_started(actors)
        for _, count, odd in ActorPool(actors).map_unordered(lambda a, j: a.make.remote(shared, j), todo):
            motions += count
            unknown += odd
            bar.update(count)
    except ray.exceptions.RayError as e:
        raise SMFError(f"a bulk worker failed: {cause(e)} (the shards written so far stay; run again to resume)") \
            from None
    finally:
        bar.close()
        for a in actors:
            ray.kill(a)
    return {"shards": plan.shards, "made": len(todo), "found": done_before, "motions": motions,
            "out_of_domain": unknown}


def cause(error: Exception) -> str:
    """The one line that says why a Ray task or actor failed: the last ``SomethingError: ...`` line of its remote
    traceback (Ray's message holds the whole of it), else the message's first line."""
    lines = [ln.strip() for ln in str(error).splitlines() if ln.strip()]
    named = [ln for ln in lines if re.match(r"^[\w.]*(Error|Exception)\b(: |$)", ln)]
    line = named[-1] if named else (lines[0] if lines else type(error).__name__)
    return line.removeprefix("stablemofusion.core.errors.").removeprefix("SMFError: ")


__all__ = ["RESTARTS", "ShardWorker", "cause", "run"]
