"""Bulk generation on a local Ray cluster: the dataset holds the motions `smf generate --prompts` makes, each once;
a run killed part way resumes without losing or repeating a motion; a worker killed mid-run is replaced."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pyarrow.dataset as ds
import pytest

from stablemofusion.bulk import ray_run
from stablemofusion.bulk.dataset import BulkPlan, joints_of, read_dataset, start
from stablemofusion.core.errors import SMFError
from stablemofusion.pipelines.motion_pipeline import MotionPipeline

PROMPTS = ["a person walks forward", "a tired man shuffles forward", "someone waves both hands",
           "a person runs in a circle", "a proud soldier marches", "an old woman bows", "a person jumps"]
SMF = "import sys; from stablemofusion.cli.main import main; sys.exit(main())"
SAMPLING = (("guidance_scale", None), ("steps", None), ("footskate", "post"), ("engine", "onnx"))


def bulk(prompts_file: Path, out: Path, *extra: str, **popen) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", SMF, "bulk", str(prompts_file), "--out", str(out), "--seconds", "2",
                             "--batch-size", "2", "--shard-batches", "1", "--engine", "onnx", "--seed", "5", "--quiet",
                             *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}, **popen)


@pytest.fixture(scope="module")
def pipe():
    return MotionPipeline.from_pretrained(backend="onnx", threads=1)


def expected(pipe, prompts: list[str], index: int, seed: int = 5, batch_size: int = 2) -> np.ndarray:
    """The joints `smf generate --prompts` gives prompt ``index``: its batch k called with seed + k."""
    k = index // batch_size
    batch = prompts[k * batch_size:(k + 1) * batch_size]
    return pipe(batch, seconds=2, batch_size=batch_size, seed=seed + k)[index % batch_size].joints


def test_the_dataset_holds_the_motions_of_generate_each_once(tmp_path, pipe):
    (tmp_path / "p.txt").write_text("\n".join(PROMPTS) + "\n")
    run = bulk(tmp_path / "p.txt", tmp_path / "out", "--workers", "2")
    stdout, stderr = run.communicate(timeout=300)
    assert run.returncode == 0, stderr
    assert json.loads(stdout.splitlines()[-1])["motions"] == len(PROMPTS)
    assert "1 of 7 prompts are unlike anything" in stderr  # 'a person jumps'
    table = read_dataset(tmp_path / "out")
    assert table.column("index").to_pylist() == list(range(len(PROMPTS)))
    assert table.column("prompt").to_pylist() == PROMPTS
    assert table.column("seed").to_pylist() == [5, 5, 6, 6, 7, 7, 8]
    assert table.column("out_of_domain").to_pylist() == [False] * 6 + [True]
    for i in range(len(PROMPTS)):
        got = joints_of(table, i)
        assert got.shape == (40, 22, 3) and table.column("frames")[i].as_py() == 40
        np.testing.assert_allclose(got, expected(pipe, PROMPTS, i), atol=1e-6)
    assert all(len(c) == 40 for c in table.column("contacts").to_pylist())
    # the folder reads as one Parquet dataset (pyarrow, and so Hugging Face datasets' "parquet" loader)
    assert ds.dataset(tmp_path / "out", format="parquet").count_rows() == len(PROMPTS)
    # the same command again finds it done
    again = bulk(tmp_path / "p.txt", tmp_path / "out")
    stdout, stderr = again.communicate(timeout=300)
    assert again.returncode == 0, stderr
    assert json.loads(stdout.splitlines()[-1]) == {"out": str(tmp_path / "out"), "shards": 4, "made": 0, "found": 4,
                                                   "motions": 0, "out_of_domain": 0}


def test_a_run_killed_part_way_resumes_with_no_motion_lost_or_repeated(tmp_path, pipe):
    prompts = [f"{PROMPTS[i % 6]} number {i}" for i in range(40)]
    (tmp_path / "p.txt").write_text("\n".join(prompts) + "\n")
    out = tmp_path / "out"
    run = bulk(tmp_path / "p.txt", out, "--workers", "1", start_new_session=True)
    deadline = time.monotonic() + 300
    while len(list(out.glob("shard-*.parquet"))) < 3 and time.monotonic() < deadline and run.poll() is None:
        time.sleep(0.05)
    os.killpg(run.pid, signal.SIGKILL)  # the driver and the cluster it started, at once
    run.wait(30)
    written = len(list(out.glob("shard-*.parquet")))
    assert 3 <= written < 20
    resumed = bulk(tmp_path / "p.txt", out, "--workers", "2")
    stdout, stderr = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, stderr
    summary = json.loads(stdout.splitlines()[-1])
    assert summary["found"] >= written and summary["found"] + summary["made"] == 20
    table = read_dataset(out)
    assert table.column("index").to_pylist() == list(range(40))  # none lost, none twice
    for i in (0, 7, 39):
        np.testing.assert_allclose(joints_of(table, i), expected(pipe, prompts, i), atol=1e-6)


def test_a_worker_killed_mid_run_is_started_again_and_its_shard_made(tmp_path, pipe):
    import ray

    prompts = [f"{PROMPTS[i % 6]} take {i}" for i in range(24)]
    plan = BulkPlan(tuple(prompts), 5, 2, 1, 2.0, SAMPLING, "shipped model")
    out = tmp_path / "out"
    killed = []

    def kill_one(actors):
        pid = ray.get(actors[0].pid.remote())

        def later():
            while not list(out.glob("shard-*.parquet")):
                time.sleep(0.02)
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
        threading.Thread(target=later, daemon=True).start()

    make = lambda: MotionPipeline.from_pretrained(backend="onnx", threads=1)  # noqa: E731
    try:
        summary = ray_run.run(plan, out, make, workers=2, progress=False, on_started=kill_one)
    finally:
        ray.shutdown()
    assert killed and summary["made"] == 12 and summary["motions"] == 24
    table = read_dataset(out)
    assert table.column("index").to_pylist() == list(range(24))
    np.testing.assert_allclose(joints_of(table, 13), expected(pipe, prompts, 13), atol=1e-6)


def test_a_folder_of_another_run_or_of_other_files_is_refused(tmp_path):
    plan = BulkPlan(tuple(PROMPTS), 5, 2, 1, 2.0, SAMPLING, "shipped model")
    assert start(tmp_path / "a", plan) == [0, 1, 2, 3]
    other = BulkPlan(tuple(PROMPTS), 6, 2, 1, 2.0, SAMPLING, "shipped model")
    with pytest.raises(SMFError, match="another run's dataset .*seed"):
        start(tmp_path / "a", other)
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "notes.txt").write_text("mine")
    with pytest.raises(SMFError, match="not empty"):
        start(tmp_path / "b", plan)


def test_bad_flags_are_one_line_errors(tmp_path):
    (tmp_path / "p.txt").write_text("a person walks\n")
    for extra, words in [(("--workers", "0"), "--workers is at least 1"), (("--seed", "-1"), "seed")]:
        run = bulk(tmp_path / "p.txt", tmp_path / "o", *extra)
        _, stderr = run.communicate(timeout=120)
        assert run.returncode == 2 and words in stderr and "Traceback" not in stderr, stderr
    run = bulk(tmp_path / "missing.txt", tmp_path / "o")
    _, stderr = run.communicate(timeout=120)
    assert run.returncode == 2 and "no such file" in stderr
    run = bulk(tmp_path / "p.txt", tmp_path / "o", "--checkpoint", str(tmp_path / "nothing"))
    _, stderr = run.communicate(timeout=120)
    assert run.returncode == 2 and "holds no portable graphs" in stderr and "Traceback" not in stderr, stderr


def test_a_workers_failure_is_named_in_one_line():
    from stablemofusion.bulk.ray_run import cause

    said = ("The actor died because of an error raised in its creation task\n  File \"x.py\", line 3, in f\n"
            "    raise SMFError(...)\nstablemofusion.core.errors.SMFError: /m holds no portable graphs (graphs.json)\n")
    assert cause(RuntimeError(said)) == "/m holds no portable graphs (graphs.json)"
    assert cause(RuntimeError("ValueError: bad\nmore")) == "ValueError: bad"
