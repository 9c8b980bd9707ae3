"""End-to-end generation time of 4 s motions, text cached, on the portable runtime (ONNX Runtime) beside the
torch path (its default engine on the CPU, and eager), in the same process: batch 1 (ms per motion) and batch 32
(motions per second), footskate off and post; and joint agreement of the two on the same prompts and seeds.

    python benchmarks/runtime_speed.py [--threads 1] [--repeats 20] [--adapter FILE]

With ``--adapter``: the shipped model adapted, on both runtimes (the torch path merges it at load; the portable
runtime runs its graphs, exported first into a temporary folder).
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _timed(fn, repeats: int) -> float:
    fn()  # warm: text cached, sessions and tables ready
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--adapter", type=Path, default=None, help="an adapter of the shipped model (smf adapt)")
    args = ap.parse_args()
    import torch

    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    warnings.simplefilter("ignore")
    torch.set_num_threads(args.threads)
    prompts = [json.loads(line)["prompt"] for line in (HERE / "prompts_freeform.jsonl").read_text().splitlines()][:32]
    graphs = None
    if args.adapter is not None:
        import tempfile

        from stablemofusion.backends.onnx_export import export_onnx
        from stablemofusion.backends.onnx_backend import default_graphs_path

        graphs = export_onnx(None, Path(tempfile.mkdtemp()) / "graphs", adapters=[args.adapter],
                             text_encoder_from=default_graphs_path())
    portable = MotionPipeline.from_pretrained(graphs, backend="onnx", threads=args.threads)
    torch_pipe = MotionPipeline.from_pretrained(adapter=args.adapter)
    runtimes = {"onnx": portable, "torch-fast": torch_pipe, "torch-eager": torch_pipe}
    engines = {"onnx": None, "torch-fast": "fast", "torch-eager": "eager"}
    out = {"threads": args.threads, "repeats": args.repeats, "seconds": 4.0,
           "adapter": None if args.adapter is None else args.adapter.name}
    for name, pipe in runtimes.items():
        kw = {} if engines[name] is None else {"engine": engines[name]}
        row = {}
        for fs in ("off", "post"):
            one = _timed(lambda: pipe(prompts[0], seconds=4, seed=0, footskate=fs, **kw), args.repeats)
            many = _timed(lambda: pipe(prompts, seconds=4, seed=0, footskate=fs, batch_size=32, **kw),
                          max(3, args.repeats // 5))
            row[fs] = {"batch_1_ms": round(one * 1000, 2), "batch_32_motions_per_s": round(32 / many, 1)}
        out[name] = row
    a = runtimes["onnx"](prompts, seconds=4, seed=list(range(32)), footskate="post")
    b = runtimes["torch-fast"](prompts, seconds=4, seed=list(range(32)), footskate="post", engine="eager")
    out["max_joint_difference_mm"] = round(max(float(np.abs(x.joints - y.joints).max()) for x, y in zip(a, b)) * 1000, 4)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
