"""Adapters on the portable runtime: the shipped model adapted (a short run on real clips) and exported as graphs
(`smf export --onnx --adapter`) makes the adapted torch model's motions without torch, and its page's JavaScript
runtime (Node.js) knows the taught captions as the Python one does."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from stablemofusion.adapters.clips import read_clips
from stablemofusion.adapters.train import AdaptConfig, adapt
from stablemofusion.cli.main import main

CLIPS = ("dataset-2_walk-turn-left_normal_001", "dataset-1_walk_normal_001")
CAPTION = "a person hops on one leg"
FOREIGN = "a person plays the violin"
PARAPHRASE = "someone hops along on one foot"  # clearly closest to the taught action: answered with CAPTION


@pytest.fixture(scope="module")
def adapted_graphs(bandai_mini_source, tmp_path_factory):
    """(graphs folder, adapter file): the shipped model taught a caption from two real clips in a few steps."""
    import torch

    torch.set_num_threads(1)
    tmp = tmp_path_factory.mktemp("portable-adapter")
    (tmp / "clips").mkdir()
    for name in CLIPS:
        shutil.copy(next(bandai_mini_source.rglob(f"{name}.bvh")), tmp / "clips" / f"{name}.bvh")
    clips, _ = read_clips(tmp / "clips", "bandai-namco", caption=CAPTION)
    cfg = AdaptConfig(rank=2, teacher_steps=3, student_steps=2, batch_size=4, pool=4, replay_prompts=4, contrast=1)
    adapt(None, clips, tmp / "hop.safetensors", cfg, name="hop", licence="CC BY-NC 4.0", progress=False)
    from stablemofusion.core.folders import model_folder

    assert main(["export", "--onnx", "--checkpoint", str(model_folder(None)), "--adapter", str(tmp / "hop.safetensors"),
                 "--out", str(tmp / "graphs")]) == 0
    return tmp / "graphs", tmp / "hop.safetensors"


def test_adapted_graphs_make_the_adapted_models_motions(adapted_graphs):
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    graphs, adapter = adapted_graphs
    rt = MotionPipeline.from_pretrained(graphs, backend="onnx", threads=1)
    torch_pipe = MotionPipeline.from_pretrained(device="cpu", adapter=adapter)
    base = MotionPipeline.from_pretrained(device="cpu")
    got = rt([CAPTION], seconds=4, seed=3, footskate="off")[0].joints
    want = torch_pipe([CAPTION], seconds=4, seed=3, footskate="off")[0].joints
    assert np.abs(got - want).max() < 1e-3  # metres
    with pytest.warns(UserWarning, match="not like anything"):  # the shipped model does not know the caption
        other = base([CAPTION], seconds=4, seed=3, footskate="off")[0].joints
    assert np.abs(other - want).max() > 1e-3
    assert rt.graphs.manifest["adapters"] == ["hop"]
    for prompt, outside in ((CAPTION, False), (FOREIGN, True)):
        assert rt.known_actions.check(prompt).out_of_domain is outside
        assert torch_pipe.known_actions.check(prompt).out_of_domain is outside
    # a paraphrase is answered with the clip's caption on both: the caption's motion, and a warning saying so
    said = rt([PARAPHRASE], seconds=4, seed=3, footskate="off")[0]
    torch_said = torch_pipe([PARAPHRASE], seconds=4, seed=3, footskate="off")[0]
    assert said.domain.answer == torch_said.domain.answer == CAPTION
    assert np.abs(said.joints - got).max() < 1e-6 and any("is answered as" in w for w in said.warnings)


@pytest.mark.skipif(shutil.which("node") is None, reason="needs Node.js for the JavaScript runtime")
def test_the_adapted_page_knows_the_taught_captions(adapted_graphs, tmp_path):
    graphs, _ = adapted_graphs
    site = tmp_path / "site"
    assert main(["site", "--checkpoint", str(graphs), "--out", str(site)]) == 0
    info = json.loads((site / "model" / "web.json").read_text())
    assert info["actions"]["names"][info["actions"]["taught_from"]:] == ["hop"]
    for prompt, outside in ((CAPTION, False), (FOREIGN, True)):
        out = subprocess.run(["node", str(site / "runtime" / "generate.mjs"), prompt, "--seconds", "2", "--footskate",
                              "off"], capture_output=True, text=True, timeout=300, check=True)
        assert json.loads(out.stdout)["outOfDomain"] is outside, prompt
    # a paraphrase answered with the clip's caption, as the Python runtime answers it: the same motion and warning
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    out = subprocess.run(["node", str(site / "runtime" / "generate.mjs"), PARAPHRASE, "--seconds", "2", "--seed", "3",
                          "--footskate", "off"], capture_output=True, text=True, timeout=300, check=True)
    got = json.loads(out.stdout)
    want = MotionPipeline.from_pretrained(graphs, backend="onnx", threads=1)([PARAPHRASE], seconds=2, seed=3,
                                                                             footskate="off")[0]
    assert want.domain.answer == CAPTION and np.abs(np.asarray(got["joints"]) - want.joints).max() < 5e-6
    assert [w for w in got["warnings"] if "is answered as" in w] == [w for w in want.warnings if "is answered as" in w]


BLENDER_SCRIPT = r"""
import bpy, json, sys
zip_path, packages, model, out, prompt = sys.argv[sys.argv.index('--') + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path)
bpy.ops.preferences.addon_enable(module='stablemofusion_addon')
prefs = bpy.context.preferences.addons['stablemofusion_addon'].preferences
prefs.packages, prefs.model = packages, model
scene = bpy.context.scene
scene.smf.prompt, scene.smf.seconds, scene.smf.seed, scene.smf.backend = prompt, 2, 3, 'LOCAL'
status = list(bpy.ops.smf.generate_motion())
json.dump({'status': status, 'joints': sys.modules['stablemofusion_addon'].motion.LAST_JOINTS.tolist()}, open(out, 'w'))
"""


def test_blender_generates_with_the_adapted_graphs(adapted_graphs, tmp_path, blender_shares_python):
    """The add-on's Model preference: the adapted graphs in Blender's own Python, the runtime's joints."""
    import site

    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    graphs, _ = adapted_graphs
    zip_path, script, out = tmp_path / "stablemofusion_addon.zip", tmp_path / "run.py", tmp_path / "out.json"
    assert main(["addon", "--out", str(zip_path)]) == 0
    script.write_text(BLENDER_SCRIPT)
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "BLENDER_USER_SCRIPTS": str(tmp_path / "scripts")}
    run = subprocess.run(["blender", "-b", "--factory-startup", "--python", str(script), "--", str(zip_path),
                          site.getsitepackages()[0], str(graphs), str(out), CAPTION], capture_output=True, text=True,
                         timeout=600, env=env)
    assert out.is_file(), run.stdout[-3000:] + run.stderr[-3000:]
    got = json.loads(out.read_text())
    assert got["status"] == ["FINISHED"]
    want = MotionPipeline.from_pretrained(graphs, backend="onnx", threads=1)([CAPTION], seconds=2, seed=3)[0].joints
    assert np.abs(np.asarray(got["joints"]) - want).max() < 1e-3
