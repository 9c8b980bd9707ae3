"""`smf bulk` on a local Ray cluster against `smf generate --prompts`, with a worker and then the whole run killed.

1. ``--generate`` prompts through `smf generate --prompts FILE --format npy` (one process), then through `smf bulk`
   with no fault: motions per second of each, start-up included;
2. ``--prompts`` prompts through `smf bulk` with ``--workers`` workers: a third of the way in one worker process is
   killed (SIGKILL; Ray starts it again and its shard is made again), two thirds of the way in the whole run (the
   driver and its cluster) is killed, then the same command resumes it;
3. the dataset read back with pyarrow: rows, prompt indices each once, and motions that differ from
   `smf generate`'s for the same prompt (the first ``--generate`` prompts; joints more than 1e-5 m apart).

The prompts are the free-form development prompts (benchmarks/prompts_freeform.jsonl), repeated to the count asked.
Prints one JSON report.

    python benchmarks/bulk_ray.py [--prompts 20000] [--generate 2000] [--workers 2] [--seconds 4]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.dataset as pads

from stablemofusion.bulk.dataset import joints_of, read_dataset

HERE = Path(__file__).resolve().parent
SMF = "import sys; from stablemofusion.cli.main import main; sys.exit(main())"
BATCH = 32


def prompts_of(count: int) -> list[str]:
    base = [json.loads(line)["prompt"] for line in (HERE / "prompts_freeform.jsonl").read_text().splitlines() if line]
    return [base[i % len(base)] for i in range(count)]


def smf(*args: str, **popen) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", SMF, *args], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "OMP_NUM_THREADS": "1"},
                            **popen)


def shards(out: Path) -> int:
    return len(list(out.glob("shard-*.parquet")))


def worker_pids() -> list[int]:
    found = subprocess.run(["pgrep", "-f", "ray::ShardWorker"], capture_output=True, text=True).stdout.split()
    return [int(p) for p in found]


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--prompts", type=int, default=20000)
    p.add_argument("--generate", type=int, default=2000)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seconds", default="4")
    a = p.parse_args()
    report = {"prompts": a.prompts, "workers": a.workers, "seconds": float(a.seconds), "batch_size": BATCH}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        prompts = prompts_of(a.prompts)
        (tmp / "all.txt").write_text("\n".join(prompts) + "\n")
        (tmp / "some.txt").write_text("\n".join(prompts[:a.generate]) + "\n")
        common = ("--seconds", a.seconds, "--batch-size", str(BATCH), "--engine", "onnx", "--seed", "0")

        t0 = time.monotonic()
        gen = smf("generate", "--prompts", str(tmp / "some.txt"), "--out", str(tmp / "gen"), "--format", "npy", *common)
        gen.communicate()
        took = time.monotonic() - t0
        report["generate"] = {"motions": a.generate, "s": took, "per_s": a.generate / took, "returncode": gen.returncode}
        t0 = time.monotonic()
        clean = smf("bulk", str(tmp / "some.txt"), "--out", str(tmp / "clean"), "--workers", str(a.workers), "--quiet",
                    *common)
        clean.communicate()
        took = time.monotonic() - t0
        report["bulk_same_prompts"] = {"motions": a.generate, "s": took, "per_s": a.generate / took,
                                       "returncode": clean.returncode}

        out = tmp / "bulk"
        total = -(-a.prompts // (BATCH * 8))
        t0 = time.monotonic()
        run = smf("bulk", str(tmp / "all.txt"), "--out", str(out), "--workers", str(a.workers), "--quiet", *common,
                  start_new_session=True)
        while shards(out) < total // 3 and run.poll() is None:
            time.sleep(0.1)
        pids = worker_pids()
        os.kill(pids[0], signal.SIGKILL)
        report["worker_killed_at_shards"] = shards(out)
        while shards(out) < 2 * total // 3 and run.poll() is None:
            time.sleep(0.1)
        os.killpg(run.pid, signal.SIGKILL)
        run.wait(60)
        report["run_killed_at_shards"] = shards(out)
        resumed = smf("bulk", str(tmp / "all.txt"), "--out", str(out), "--workers", str(a.workers), "--quiet", *common)
        stdout, _ = resumed.communicate()
        took = time.monotonic() - t0
        report["bulk"] = {"motions": a.prompts, "s": took, "per_s": a.prompts / took, "shards": total,
                          "resumed": json.loads(stdout.splitlines()[-1]) if stdout else None,
                          "returncode": resumed.returncode}

        table = read_dataset(out)
        index = table.column("index").to_numpy()
        report["dataset"] = {"rows": table.num_rows, "pyarrow_dataset_rows": pads.dataset(out, format="parquet").count_rows(),
                             "indices_each_once": bool(np.array_equal(np.sort(index), np.arange(a.prompts))),
                             "bytes": sum(f.stat().st_size for f in out.glob("*.parquet"))}
        files = list((tmp / "gen").glob("*_joints.npy"))  # NNN_words_joints.npy: NNN the prompt's index
        wrong = 0
        for f in files:
            wrong += float(np.abs(np.load(f) - joints_of(table, int(f.name.split("_", 1)[0]))).max()) > 1e-5
        report["differ_from_generate"] = {"checked": len(files), "differ": wrong}
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
