"""The published distributions, built from this checkout: the package's wheel holds what the default path runs,
each weight once, under 62 MB, with both licences in its metadata; the teacher is a distribution of its own, of
the same version, installed into the folders the package reads it from."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from email.parser import Parser
from pathlib import Path

import pytest

from stablemofusion import __version__

ROOT = Path(__file__).resolve().parents[1]
TEACHER_FILES = {"stablemofusion/assets/default_model/teacher/" + f for f in ("config.json", "Mean.npy", "Std.npy")} | {
    "stablemofusion/assets/default_model/onnx/teacher/" + f
    for f in ("condition.onnx", "denoise.onnx", "Mean.npy", "Std.npy", "solvers.npz")}


def build_wheel(project: Path, out: Path) -> Path:
    out.mkdir()
    subprocess.run([sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", str(out), str(project)],
                   check=True, capture_output=True, cwd=out)
    (wheel,) = out.glob("*.whl")
    return wheel


def metadata(wheel: zipfile.ZipFile):
    name = next(n for n in wheel.namelist() if n.endswith(".dist-info/METADATA"))
    return Parser().parsestr(wheel.read(name).decode("utf-8"))


@pytest.fixture(scope="module")
def wheels(tmp_path_factory):
    """Both wheels, built from a copy of the checkout (a build leaves build/ folders behind)."""
    pytest.importorskip("build", reason="the build package is not installed (the test extra has it)")
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "MANIFEST.in", "README.md", "LICENSE"):
        shutil.copyfile(ROOT / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info", "build")
    shutil.copytree(ROOT / "stablemofusion", src / "stablemofusion", ignore=ignore)
    shutil.copytree(ROOT / "packaging", src / "packaging", symlinks=True, ignore=ignore)  # its links into the package
    out = tmp_path_factory.mktemp("dist")
    return build_wheel(src, out / "main"), build_wheel(src / "packaging" / "teacher", out / "teacher")


def test_the_wheel_holds_the_default_path_once_under_62_mb_with_its_licences(wheels):
    main, _ = wheels
    assert main.stat().st_size <= 62e6  # 59.4 MB before the two robots (4 MB of meshes, 1.9 MB compressed)
    with zipfile.ZipFile(main) as z:
        names = set(z.namelist())
        meta = metadata(z)
    assert not names & TEACHER_FILES and not any(n.endswith("model.safetensors") for n in names)
    assert not any("asyncify" in n or "webgpu" in n for n in names)  # the page's WebGPU build: smf site --webgpu
    for need in ("default_model/onnx/text_encoder.onnx", "default_model/onnx/denoise.onnx", "default_model/config.json",
                 "site/vendor/onnxruntime-web/ort-wasm-simd-threaded.wasm", "viewer/index.html"):
        assert "stablemofusion/assets/" + need in names
    assert meta["Version"] == __version__
    assert meta["License-Expression"] == "MIT AND CC-BY-NC-4.0 AND Apache-2.0 AND BSD-3-Clause"
    files = meta.get_all("License-File")
    assert "LICENSE" in files and "stablemofusion/assets/default_model/LICENSE" in files
    assert "stablemofusion/assets/robots/g1/LICENSE.txt" in files and "stablemofusion/assets/robots/h1/LICENSE.txt" in files
    assert any(f"dist-info/licenses/{f}" in n for f in files for n in names)
    assert f"stablemofusion-teacher=={__version__}; extra == \"teacher\"" in meta.get_all("Requires-Dist")


def test_the_teacher_is_its_own_distribution_of_the_same_version(wheels):
    _, teacher = wheels
    with zipfile.ZipFile(teacher) as z:
        names = {n for n in z.namelist() if ".dist-info/" not in n}
        meta = metadata(z)
        for name in TEACHER_FILES:  # the checkout's own files, byte for byte
            assert z.read(name) == (ROOT / name).read_bytes()
    assert names == TEACHER_FILES
    assert meta["Version"] == __version__ and meta["License-Expression"] == "CC-BY-NC-4.0"
    assert f"stablemofusion=={__version__}" in meta.get_all("Requires-Dist")


@pytest.fixture(scope="module")
def without_teacher(tmp_path_factory):
    """The shipped model as the package's wheel installs it, without the teacher's distribution."""
    from stablemofusion.pipelines.motion_pipeline import default_model_path

    folder = tmp_path_factory.mktemp("installed") / "default_model"
    shutil.copytree(default_model_path(), folder, ignore=shutil.ignore_patterns("teacher"))
    return folder


def test_without_the_teacher_the_student_runs_and_teacher_says_how_to_install_it(without_teacher, capsys):
    from stablemofusion.cli.main import main
    from stablemofusion.core.errors import SMFError
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    motion = MotionPipeline.from_pretrained(without_teacher, backend="onnx", threads=1)("a person walks", seconds=2, seed=0)[0]
    assert motion.joints.shape == (40, 22, 3)
    with pytest.raises(SMFError, match=r"the teacher is not installed: pip install 'stablemofusion\[teacher\]'"):
        MotionPipeline.from_pretrained(without_teacher, backend="onnx", teacher=True)
    for engine in ("onnx", "eager"):  # the portable runtime's graphs, the torch backend's folder
        code = main(["generate", "a person walks", "--seconds", "2", "--teacher", "--engine", engine,
                     "--checkpoint", str(without_teacher), "--out", str(without_teacher.parent / "out")])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and "stablemofusion[teacher]" in err, err
