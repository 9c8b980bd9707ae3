"""The final stage's graphs (assets/final_stage/: the cleanup and its contacts, exported from the Python functions)
against the Python functions themselves, on the same rigid joints: every path kind and explicit waypoints, walks,
runs and standing motions; run by ONNX Runtime in Python and by ONNX Runtime Web in Node.js, as the page and Node
run them. Everything computes in float64, so they agree to rounding (goal: 1e-3 mm; asserted 1e-9 m). A change to
the Python cleanup that is not exported again (`smf export --final-stage`) fails here."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from stablemofusion.footskate.cleanup import CleanupConfig, clean_joints, detect_contacts
from stablemofusion.runtime.pipeline import PortablePipeline
from stablemofusion.site import final_stage_graph

NODE = shutil.which("node")
ORT_WEB = Path(__file__).resolve().parents[2] / "stablemofusion" / "assets" / "site" / "vendor" / "onnxruntime-web"
DRIVER = """
import { readFileSync } from 'node:fs';
import { pathToFileURL } from 'node:url';
const [ortDir, contactsFile, cleanupFile] = process.argv.slice(2);
const ort = await import(pathToFileURL(ortDir + '/ort.wasm.min.mjs').href);
ort.env.wasm.numThreads = 1;
ort.env.wasm.wasmPaths = pathToFileURL(ortDir + '/').href;
const contacts = await ort.InferenceSession.create(readFileSync(contactsFile));
const cleanup = await ort.InferenceSession.create(readFileSync(cleanupFile));
const jobs = JSON.parse(readFileSync(0, 'utf8'));
const out = [];
for (const m of jobs) {
  const joints = new ort.Tensor('float64', Float64Array.from(m.x), [1, m.T, 22, 3]);
  const c = await contacts.run({ joints });
  const r = await cleanup.run({ joints, bone_lengths: new ort.Tensor('float64', Float64Array.from(m.lengths), [1, 22]) });
  out.push({ joints: Array.from(r.joints_out.data), held: Array.from(r.held.data, Number),
             contacts: Array.from(c.contacts.data, Number) });
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
]


@pytest.fixture(scope="module")
def cases():
    """Rigid joints, bone lengths, and the Python cleanup's joints, held frames and contacts of each case."""
    pipe = PortablePipeline.from_pretrained(threads=1)
    config = CleanupConfig()
    out = []
    for k, (prompt, path) in enumerate(CASES):
        body = pipe(prompt, seed=k, footskate="off", path=path)[0].motion
        x = body.joints()
        c = detect_contacts(x, pipe.fps, config)
        joints, held = clean_joints(x, c, body.bone_lengths, pipe.fps, config)
        out.append((x, body.bone_lengths, joints, held, c))
    assert any(np.abs(w - x).max() > 0.05 for x, _, w, _, _ in out)  # the cleanup moved something
    return out


def test_the_graphs_are_the_python_final_stage(cases):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    cleanup = ort.InferenceSession(str(final_stage_graph("cleanup")), options, providers=["CPUExecutionProvider"])
    contacts = ort.InferenceSession(str(final_stage_graph("contacts")), options, providers=["CPUExecutionProvider"])
    for (prompt, _), (x, lengths, want, held, c) in zip(CASES, cases):
        got, got_held = cleanup.run(None, {"joints": x[None], "bone_lengths": lengths[None]})
        assert np.abs(got[0] - want).max() < 1e-9, prompt
        assert np.array_equal(got_held[0], held), prompt
        assert np.array_equal(contacts.run(None, {"joints": x[None]})[0][0], c), prompt
    # a batch of motions of one length: each one's result is the one it gets alone
    n = min(len(cases[0][0]), len(cases[1][0]))
    x = np.stack([cases[0][0][:n], cases[1][0][:n]])
    lengths = np.stack([cases[0][1], cases[1][1]])
    got, _ = cleanup.run(None, {"joints": x, "bone_lengths": lengths})
    alone = [clean_joints(x[i], detect_contacts(x[i], 20.0, CleanupConfig()), lengths[i], 20.0)[0] for i in range(2)]
    assert np.abs(got - np.stack(alone)).max() < 1e-9


@pytest.mark.skipif(NODE is None, reason="Node.js is not installed (apt-get install nodejs)")
def test_node_runs_the_same_final_stage(tmp_path, cases):
    driver = tmp_path / "driver.mjs"
    driver.write_text(DRIVER)
    jobs = [{"x": x.ravel().tolist(), "T": len(x), "lengths": lengths.tolist()} for x, lengths, _, _, _ in cases]
    run = subprocess.run([NODE, str(driver), str(ORT_WEB), str(final_stage_graph("contacts")),
                          str(final_stage_graph("cleanup"))], input=json.dumps(jobs), capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    for (prompt, _), g, (x, _, want, held, c) in zip(CASES, json.loads(run.stdout), cases):
        assert np.abs(np.asarray(g["joints"]).reshape(want.shape) - want).max() < 1e-9, prompt
        assert np.array_equal(np.asarray(g["held"], bool).reshape(held.shape), held), prompt
        assert np.array_equal(np.asarray(g["contacts"], bool).reshape(c.shape), c), prompt
