"""The final stage's graphs (assets/final_stage/: the path words' bend, following explicit points, decoding and the
rigid fit, the cleanup and its contacts, the pose, a timeline window's continuation; exported from the Python
functions) against the Python functions themselves, on the same inputs: every path kind and explicit waypoints (timed
and not), walks, runs and standing motions; run by ONNX Runtime in Python and by ONNX Runtime Web in Node.js, as the
page and Node run them. Everything computes in float64, so they agree to rounding (goal: 1e-3 mm; asserted 1e-9 m,
1e-9 rad, 1e-6 degrees). A change to the Python final stage that is not exported again (`smf export --final-stage`)
fails here."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from stablemofusion.core.edit_plan import continue_features
from stablemofusion.footskate.cleanup import CleanupConfig, clean_joints, detect_contacts
from stablemofusion.motion.bvh import BVH_ORDER
from stablemofusion.motion.features import joints_from_features
from stablemofusion.motion.rigid import DEFAULT_FIT
from stablemofusion.motion.rigid_batch import fit_joints, pose_joints
from stablemofusion.motion.rotation import matrix_to_euler
from stablemofusion.core.path_plan import KINDS, Waypoints, bend, follow_waypoints, parse_path
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve.site import FINAL_STAGE, final_stage_graph

NODE = shutil.which("node")
ORT_WEB = Path(__file__).resolve().parents[2] / "stablemofusion" / "assets" / "site" / "vendor" / "onnxruntime-web"
DRIVER = """
import { readFileSync } from 'node:fs';
import { pathToFileURL } from 'node:url';
const [ortDir, folder] = process.argv.slice(2);
const ort = await import(pathToFileURL(ortDir + '/ort.wasm.min.mjs').href);
ort.env.wasm.numThreads = 1;
ort.env.wasm.wasmPaths = pathToFileURL(ortDir + '/').href;
const sessions = {};
const jobs = JSON.parse(readFileSync(0, 'utf8'));
const make = { float64: Float64Array, int64: (v) => BigInt64Array.from(v.map(BigInt)), bool: Uint8Array };
const out = [];
for (const { graph, feeds } of jobs) {
  sessions[graph] ??= await ort.InferenceSession.create(readFileSync(`${folder}/${graph}.onnx`));
  const tensors = Object.fromEntries(Object.entries(feeds).map(([k, { type, data, dims }]) =>
    [k, new ort.Tensor(type, type === 'int64' ? make.int64(data) : make[type].from(data), dims)]));
  const got = await sessions[graph].run(tensors);
  out.push(Object.fromEntries(Object.entries(got).map(([k, t]) => [k, Array.from(t.data, Number)])));
}
process.stdout.write(JSON.stringify(out));
"""
CASES = [  # (prompt, path) covering every path kind of the lexicon and explicit waypoints
    ("a man walks in a circle", None), ("a person runs in a circle clockwise", None),
    ("a woman walks and turns left", None), ("a child runs zigzagging forward", None),
    ("a person walks forward and comes back", None), ("a man walks sideways to the left", None),
    ("a person walks in a half circle", None), ("someone walks along a curve to the right", None),
    ("a person waves both hands happily", None), ("an old man walks forward slowly", None),
    ("a person walks", {"points": [[0, 0], [0, 3], [3, 3], [3, 0], [0, 0]]}),
    ("a person runs", {"points": [[0, 0], [1, 1.5], [-1, 3], [1, 4.5]]}),
    ("a person walks", {"points": [[0, 0], [2, 0], [2, 2]], "times": [0, 1.5, 4]}),
]
FPS = 20.0


def feed(**arrays) -> dict:
    """Graph inputs as numpy arrays of the graph's types (float64, int64, bool)."""
    return {k: np.asarray(v) for k, v in arrays.items()}


@pytest.fixture(scope="module")
def jobs():
    """(case, graph, inputs, the Python function's outputs) for every graph on every case it applies to."""
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    lengths = np.asarray(pipe.skeleton.bone_lengths)[None]
    config = CleanupConfig()
    out, last = [], None
    for k, (prompt, path) in enumerate(CASES):
        spec = parse_path(prompt)
        raw = pipe(prompt if spec is None else spec.prompt, seconds=4, seed=k, footskate="off")[0].features
        if last is not None and k < 4:  # a timeline's window continuing the motion before it (the last 1 s, or 2 frames)
            keep = 20 if k < 3 else 2
            known = np.zeros_like(raw)
            known[:keep] = last[-keep:]
            out.append((prompt, "continue", feed(features=raw[None], known=known[None], keep=np.array([keep])),
                        [continue_features(raw, known, keep)[None]]))
        last = raw
        if path is not None:
            wp = Waypoints.read(path)
            timed = wp.times is not None
            f, start, origin = follow_waypoints(raw, wp, FPS)
            out.append((prompt, "follow", feed(features=raw[None], points=wp.points[None],
                                               times=(wp.times if timed else np.zeros(len(wp.points)))[None],
                                               timed=np.array([timed])),
                        [f[None], np.array([start]), origin[None]]))
        elif spec is not None:
            f = bend(raw, spec)
            out.append((prompt, "bend", feed(features=raw[None], kind=np.array([KINDS.index(spec.kind)]),
                                             angle=np.array([math.radians(spec.angle)])), [f[None]]))
        else:
            f = raw
        x = fit_joints(joints_from_features(f)[None], lengths, DEFAULT_FIT.iterations)
        out.append((prompt, "rigid", feed(features=f[None], bone_lengths=lengths), [x]))
        c = detect_contacts(x[0], FPS, config)
        cleaned, held = clean_joints(x[0], c, lengths[0], FPS, config)
        out.append((prompt, "contacts", feed(joints=x), [c[None]]))
        out.append((prompt, "cleanup", feed(joints=x, bone_lengths=lengths), [cleaned[None], held[None]]))
        offsets, local = pose_joints(cleaned[None], lengths)
        out.append((prompt, "pose", feed(joints=cleaned[None], bone_lengths=lengths),
                    [offsets, local, matrix_to_euler(local, BVH_ORDER)]))
    assert {g for _, g, _, _ in out} == set(FINAL_STAGE)  # every graph is checked
    assert any(np.abs(w[0] - i["joints"]).max() > 0.05 for _, g, i, w in out if g == "cleanup")  # it moved feet
    return out


def assert_equal(prompt: str, graph: str, got: list, want: list) -> None:
    """Outputs equal: bool exactly; joints (m), features, rotations, radians to 1e-9; the pose's BVH angles (its
    last output, degrees) to 1e-6."""
    for k, (g, w) in enumerate(zip(got, want)):
        g = np.asarray(g).reshape(w.shape)
        if w.dtype == bool:
            assert np.array_equal(g.astype(bool), w), (prompt, graph)
        else:
            tol = 1e-6 if graph == "pose" and k == 2 else 1e-9
            assert np.abs(g - w).max() < tol, (prompt, graph, np.abs(g - w).max())


def test_the_graphs_are_the_python_final_stage(jobs):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    sessions = {name: ort.InferenceSession(str(final_stage_graph(name)), options, providers=["CPUExecutionProvider"])
                for name in FINAL_STAGE}
    for prompt, graph, inputs, want in jobs:
        assert_equal(prompt, graph, sessions[graph].run(None, inputs), want)
    # a batch of motions of one length: each one's result is the one it gets alone
    rigid = [(i, w) for _, g, i, w in jobs if g == "rigid"][:2]
    n = min(i["features"].shape[1] for i, _ in rigid)
    got = sessions["rigid"].run(None, {"features": np.concatenate([i["features"][:, :n] for i, _ in rigid]),
                                       "bone_lengths": np.concatenate([i["bone_lengths"] for i, _ in rigid])})[0]
    alone = [sessions["rigid"].run(None, {"features": i["features"][:, :n], "bone_lengths": i["bone_lengths"]})[0]
             for i, _ in rigid]
    assert np.abs(got - np.concatenate(alone)).max() < 1e-9
    x = np.concatenate([w[0][:, :n] for _, w in rigid])
    lengths = np.concatenate([i["bone_lengths"] for i, _ in rigid])
    got, _ = sessions["cleanup"].run(None, {"joints": x, "bone_lengths": lengths})
    alone = [clean_joints(x[i], detect_contacts(x[i], FPS, CleanupConfig()), lengths[i], FPS)[0] for i in range(2)]
    assert np.abs(got - np.stack(alone)).max() < 1e-9


@pytest.mark.skipif(NODE is None, reason="Node.js is not installed (apt-get install nodejs)")
def test_node_runs_the_same_final_stage(tmp_path, jobs):
    driver = tmp_path / "driver.mjs"
    driver.write_text(DRIVER)
    sent = [{"graph": graph, "feeds": {k: {"type": {"f": "float64", "i": "int64", "b": "bool"}[v.dtype.kind],
                                           "data": v.ravel().tolist(), "dims": list(v.shape)}
                                       for k, v in inputs.items()}} for _, graph, inputs, _ in jobs]
    folder = final_stage_graph("rigid").parent
    run = subprocess.run([NODE, str(driver), str(ORT_WEB), str(folder)], input=json.dumps(sent), capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    for (prompt, graph, _, want), got in zip(jobs, json.loads(run.stdout)):
        assert_equal(prompt, graph, list(got.values()), want)
