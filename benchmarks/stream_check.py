"""Live streams checked, over a real WebSocket against `smf serve` (the shipped model) on
127.0.0.1:

    OMP_NUM_THREADS=1 python benchmarks/stream_check.py [--classifier CL --data CORPUS] [--seconds 30]

1. One stream of ``--seconds`` (30) with a new prompt every ``--every`` (6) seconds. The client starts its play
   clock when the first frames arrive (frame f plays at start + f / fps) and measures, for every frame, its play
   time minus its arrival (the margin: negative = late); each new prompt's delay on screen (the play time of
   the first frame with its prompt_index minus the time it was sent); the largest joint step (largest over
   joints of a joint's move from one frame to the next) at each switch of prompt against the 99th percentile
   of the steps inside the stream; with ``--classifier`` and ``--data``, the motion classifier's content label
   of every segment (the frames of one prompt_index, as received, converted to features), among the contents
   of the corpus's dataset 2.
2. ``--streams`` (4) such streams at once (seeds and prompt orders differ): late frames and worst margin per
   stream.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time

import httpx
import numpy as np

HOST = "127.0.0.1"
START_TIMEOUT_S = 600
PROMPTS = [("a person walks forward", "walk"), ("a person waves both hands", "wave-both-hands"),
           ("a person runs forward", "run"), ("a person raises the right hand", "raise-up-right-hand"),
           ("a person raises both hands", "raise-up-both-hands")]


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


async def one_stream(url: str, seed: int, prompts: list[str], seconds: float, every: float) -> dict:
    """A stream of ``seconds`` with prompt k sent ``k * every`` s after the first frames arrived."""
    from websockets.asyncio.client import connect

    messages, sends = [], []  # (arrival, message); (time, prompt index)
    async with connect(url, max_size=2**22) as ws:
        sends.append((time.monotonic(), 0))
        await ws.send(json.dumps({"prompt": prompts[0], "seed": seed}))
        start, frames, k = None, 0, 1
        deadline = time.monotonic() + seconds + 60
        while frames < seconds * 20 and time.monotonic() < deadline:
            wait = None if start is None or k >= len(prompts) else start + k * every - time.monotonic()
            try:
                raw = await asyncio.wait_for(ws.recv(), timeout=max(wait, 0.0) if wait is not None else 30)
            except asyncio.TimeoutError:
                if wait is None:
                    raise
                sends.append((time.monotonic(), k))
                await ws.send(json.dumps({"prompt": prompts[k]}))
                k += 1
                continue
            now = time.monotonic()
            m = json.loads(raw)
            if m["type"] != "frames":
                raise SystemExit(f"server error: {m}")
            start = now if start is None else start
            messages.append((now, m))
            frames += len(m["joints"])
        await ws.send(json.dumps({"stop": True}))
    return {"start": start, "messages": messages, "sends": sends, "prompts": prompts}


def figures(run: dict) -> dict:
    start, fps = run["start"], run["messages"][0][1]["fps"]
    margins, index, joints = [], [], []
    for arrival, m in run["messages"]:
        n = len(m["joints"])
        margins += [start + (m["start"] + i) / fps - arrival for i in range(n)]
        index += [m["prompt_index"]] * n
        joints += m["joints"]
    joints, index = np.array(joints), np.array(index)
    onscreen = []
    for t, k in run["sends"][1:]:
        first = np.flatnonzero(index == k)
        onscreen.append(float(start + first[0] / fps - t) if len(first) else float("inf"))
    step = np.linalg.norm(np.diff(joints, axis=0), axis=-1).max(-1)  # step[t]: frame t -> t + 1
    switch = np.flatnonzero(np.diff(index) != 0)
    inside = np.delete(step, switch)
    return {"frames": len(joints), "late_frames": int(sum(m < 0 for m in margins)),
            # the first message starts the clock (its margins are 0, 0.05, ... by definition): the worst of the rest
            "worst_margin_s": round(float(min(margins[len(run["messages"][0][1]["joints"]):])), 3),
            "onscreen_s": [round(x, 3) for x in onscreen],
            "switch_steps_m": [round(float(step[s]), 4) for s in switch],
            "inside_p99_m": round(float(np.percentile(inside, 99)), 4),
            "inside_max_m": round(float(inside.max()), 4), "joints": joints, "index": index}


def classify(results: list[tuple[dict, list[str]]], classifier: str, data: str) -> dict:
    from stablemofusion.data.labels import corpus_labels
    from stablemofusion.eval.classifier import dataset_labels, load_classifier
    from stablemofusion.motion.features import features_from_joints
    from stablemofusion.motion.skeleton import get_skeleton

    clf = load_classifier(classifier)
    allowed = (dataset_labels(corpus_labels(data), 2)[0], ())
    sk = get_skeleton("humanml3d")
    feats, wanted = [], []
    for fig, labels in results:
        for k, label in enumerate(labels):
            seg = fig["joints"][fig["index"] == k].astype(np.float64)
            if len(seg) >= 10:
                feats.append(features_from_joints(seg, sk))
                wanted.append(label)
    got = [c for c, _ in clf.predict(feats, [allowed] * len(feats))]
    return {"recognised": sum(g == w for g, w in zip(got, wanted)), "segments": len(wanted),
            "labels": [f"{w}->{g}" for w, g in zip(wanted, got)]}


async def idle(base: str, timeout: float = 30.0) -> None:
    """Until the server has no stream open (a stopped one is released as soon as its window is done)."""
    async with httpx.AsyncClient(base_url=base) as client:
        deadline = time.monotonic() + timeout
        while (await client.get("/v1/health")).json()["streams"]["active"] and time.monotonic() < deadline:
            await asyncio.sleep(0.1)


async def main_async(base: str, url: str, args) -> dict:
    order = [p for p, _ in PROMPTS]
    single = await one_stream(url, 0, order, args.seconds, args.every)
    await idle(base)
    rotations = [order[i:] + order[:i] for i in range(args.streams)]
    many = await asyncio.gather(*[one_stream(url, 10 + i, rotations[i], args.seconds, args.every)
                                  for i in range(args.streams)])
    return {"single": single, "many": list(many), "labels": {p: lab for p, lab in PROMPTS}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--every", type=float, default=6.0)
    ap.add_argument("--streams", type=int, default=4)
    ap.add_argument("--threads", type=int, default=1, help="torch threads of the server's workers (default 1)")
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--classifier", default=None)
    ap.add_argument("--data", default=None, help="the corpus whose labels name the classifier's contents")
    args = ap.parse_args()
    port = free_port()
    cmd = [sys.executable, "-m", "stablemofusion.cli.main", "serve", "--host", HOST, "--port", str(port),
           "--device", "cpu", "--threads", str(args.threads), "--max-streams", str(max(args.streams, 1))]
    cmd += ["--checkpoint", args.checkpoint] if args.checkpoint else []
    log = tempfile.TemporaryFile()
    server = subprocess.Popen(cmd, env={**os.environ, "OMP_NUM_THREADS": str(args.threads)},
                              stdout=subprocess.DEVNULL, stderr=log)
    base = f"http://{HOST}:{port}"
    try:
        for _ in range(int(START_TIMEOUT_S / 0.5)):
            try:
                h = httpx.get(base + "/v1/health", timeout=2)
                if h.status_code == 200 and h.json()["streams"]["state"] == "ready":
                    break
            except httpx.HTTPError:
                pass
            if server.poll() is not None:
                break
            time.sleep(0.5)
        else:
            raise SystemExit("the server did not become ready")
        load_before = os.getloadavg()[0]
        runs = asyncio.run(main_async(base, f"ws://{HOST}:{port}/v1/stream", args))
        health = httpx.get(base + "/v1/health", timeout=5).json()["streams"]
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(30)
    single = figures(runs["single"])
    many = [figures(r) for r in runs["many"]]
    report = {"single_stream": {k: v for k, v in single.items() if k not in ("joints", "index")},
              f"{len(many)}_streams": [{k: f[k] for k in ("frames", "late_frames", "worst_margin_s", "onscreen_s")}
                                      for f in many],
              "stream_worker": {k: health[k] for k in ("windows", "cut_frames", "call_ms_median", "call_ms_max",
                                                    "windows_per_call")},
              "load_average_1min": [round(load_before, 2), round(os.getloadavg()[0], 2)]}
    if args.classifier and args.data:
        labels = runs["labels"]
        report["classifier_single"] = classify([(single, [labels[p] for p in runs["single"]["prompts"]])],
                                               args.classifier, args.data)
        report[f"classifier_{len(many)}_streams"] = classify(
            [(f, [labels[p] for p in r["prompts"]]) for f, r in zip(many, runs["many"])], args.classifier, args.data)
    report["command"] = " ".join(["python benchmarks/stream_check.py"] + sys.argv[1:])
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
