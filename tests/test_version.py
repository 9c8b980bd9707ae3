"""What made a motion is written in it: the package's version (`smf --version`, the changelog's newest entry, the
installed metadata) and the model's (its card, its config, its graphs) in every output that carries metadata:
JSON files and answers, glb files and answers, the server's health."""

from __future__ import annotations

import json
import re
from importlib import metadata
from pathlib import Path

import pygltflib
import pytest

from stablemofusion import __version__
from stablemofusion.cli.main import main
from stablemofusion.pipelines.motion_pipeline import default_model_path
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve import create_app
from serve.serve_helpers import call

ROOT = Path(__file__).resolve().parents[1]
MODEL_VERSION = "bandai-v4"


def test_one_version_in_the_code_the_metadata_the_changelog_and_smf_version(capsys):
    assert metadata.version("stablemofusion") == __version__
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"smf {__version__}"
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert re.findall(r"^## (\S+)", changelog, re.M)[0] == __version__  # the newest entry is this version


def test_the_model_names_its_version_in_its_card_config_and_graphs():
    path = default_model_path()
    assert MODEL_VERSION in (path / "MODEL_CARD.md").read_text(encoding="utf-8")
    for config in (path / "config.json", path / "teacher" / "config.json"):
        assert json.loads(config.read_text())["export"]["version"] == MODEL_VERSION
    assert json.loads((path / "onnx" / "graphs.json").read_text())["model_version"] == MODEL_VERSION


@pytest.mark.parametrize("engine", ["onnx", "eager"])
def test_files_say_what_made_them(tmp_path, engine):
    assert main(["generate", "a person walks forward", "--seconds", "2", "--seed", "0", "--format", "json,glb",
                 "--engine", engine, "--out", str(tmp_path)]) == 0
    body = json.loads(next(tmp_path.glob("*.json")).read_text())
    extras = pygltflib.GLTF2.load(str(next(tmp_path.glob("*.glb")))).extras
    for meta in (body, extras):
        assert meta["model_version"] == MODEL_VERSION and meta["smf_version"] == __version__


def test_answers_say_what_made_them():
    app = create_app(MotionPipeline.from_pretrained(backend="onnx", threads=1))
    request = {"prompt": "a person walks forward", "seconds": 2, "seed": 0}
    js, glb, health = call(app, ("POST", "/v1/generate", request), ("POST", "/v1/generate?format=glb", request),
                           ("GET", "/v1/health", None))
    extras = pygltflib.GLTF2.load_from_bytes(glb.content).extras
    for meta in (js.json(), extras, health.json()):
        assert meta["model_version"] == MODEL_VERSION and meta["smf_version"] == __version__
