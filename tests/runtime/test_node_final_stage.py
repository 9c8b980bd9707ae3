"""The final stage alone, JavaScript (assets/runtime/cleanup.js run by Node.js) against Python
(footskate/cleanup.py's clean_joints), on the same rigid joints: every path kind and explicit waypoints, walks,
runs and standing motions. Both compute in float64, so they agree to rounding (goal: 1e-3 mm; asserted 1e-9 m)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from stablemofusion.footskate.cleanup import CleanupConfig, clean_joints, detect_contacts
from stablemofusion.runtime.pipeline import PortablePipeline
from stablemofusion.site import cleanup_settings

NODE = shutil.which("node")
pytestmark = pytest.mark.skipif(NODE is None, reason="Node.js is not installed (apt-get install nodejs)")
CLEANUP_JS = Path(__file__).resolve().parents[2] / "stablemofusion" / "assets" / "runtime" / "cleanup.js"
DRIVER = """
import { readFileSync } from 'node:fs';
const { cleanupRigid } = await import(process.argv[2]);
const jobs = JSON.parse(readFileSync(0, 'utf8'));
const out = jobs.motions.map((m) => {
  const { joints, held } = cleanupRigid(Float64Array.from(m.x), m.T, m.lengths, jobs.fps, jobs.settings);
  return { joints: Array.from(joints), held };
});
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


def test_the_javascript_final_stage_is_the_python_one(tmp_path):
    pipe = PortablePipeline.from_pretrained(threads=1)
    config = CleanupConfig()
    motions, want = [], []
    for k, (prompt, path) in enumerate(CASES):
        body = pipe(prompt, seed=k, footskate="off", path=path)[0].motion
        x = body.joints()
        motions.append({"x": x.ravel().tolist(), "T": len(x), "lengths": body.bone_lengths.tolist()})
        want.append(clean_joints(x, detect_contacts(x, pipe.fps, config), body.bone_lengths, pipe.fps, config))
    driver = tmp_path / "driver.mjs"
    driver.write_text(DRIVER)
    jobs = {"fps": pipe.fps, "settings": cleanup_settings(pipe.fps), "motions": motions}
    run = subprocess.run([NODE, str(driver), CLEANUP_JS.as_uri()], input=json.dumps(jobs), capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout)
    for (prompt, _), g, (w, held) in zip(CASES, got, want):
        diff = np.abs(np.asarray(g["joints"]).reshape(w.shape) - w).max()
        assert diff < 1e-9, (prompt, diff)
        assert np.array_equal(np.asarray(g["held"], bool).T, held), prompt
    assert any(np.abs(w - np.asarray(m["x"]).reshape(w.shape)).max() > 0.05 for (w, _), m in zip(want, motions))
