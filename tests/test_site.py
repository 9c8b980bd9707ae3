"""The static site (`smf site`) in Debian's Chromium, served by `python -m http.server` (no cross-origin isolation:
single-threaded WebAssembly): window.smf at the load event, a 4 s motion within 5 mm of the runtime's joints for
the same prompt, seed and length, its BVH and .glb made in the page (read back: the same joints; the .glb valid
for the Khronos validator where it is installed), no request outside its origin, no console error, the stick
figure drawn. Skipped where Chromium or Playwright is absent (CI installs both)."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time

import json
from pathlib import Path

import numpy as np
import pytest
from motion.gltf_tools import VALIDATE_JS, gltf_validator_dir, play_node_tree

from stablemofusion.cli.main import main
from stablemofusion.motion.bvh import forward_kinematics, read_bvh
from stablemofusion.motion.skeleton import HUMANML3D
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve.site import WEBGPU_FILES

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
playwright = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (apt-get install chromium)")
FLAGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run"]
PROMPT, SEED = "a person waves both hands happily", 7


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """`smf site` written and served by python -m http.server on a free loopback port."""
    folder = tmp_path_factory.mktemp("site") / "site"
    assert main(["site", "--out", str(folder)]) == 0
    server, url = serve(folder)
    yield url
    server.terminate()
    server.wait(10)


def test_the_page_generates_the_runtimes_motion_offline(served, tmp_path):
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        page = browser.new_page(viewport={"width": 900, "height": 600})
        logs, outside = [], []
        page.on("console", lambda m: logs.append(m.text) if m.type in ("error", "warning") else None)
        page.on("pageerror", lambda e: logs.append(str(e)))
        page.on("request", lambda r: None if r.url.startswith(served) else outside.append(r.url))
        page.goto(served, wait_until="load")
        assert page.evaluate("typeof window.smf.generate") == "function"  # there at the load event
        joints = page.evaluate(f"window.smf.generate({{prompt: '{PROMPT}', seconds: 4, seed: {SEED}, footskate: 'off'}})"
                               ".then(() => window.smf.lastMotion.joints)")
        bad = page.evaluate("window.smf.generate({prompt: 'a person walks', seconds: 4, seed: 1, footskate: 'loop'})"
                            ".then(() => '', (e) => e.message)")
        bvh = page.evaluate("window.smf.file('bvh')")  # of the motion made with footskate off
        glb = page.evaluate("window.smf.file('glb').then((b) => Array.from(b))")
        cleaned = page.evaluate(f"window.smf.generate({{prompt: '{PROMPT}', seconds: 4, seed: {SEED}}})"  # default: post
                                ".then(() => window.smf.lastMotion.joints)")
        page.wait_for_timeout(300)
        shot = tmp_path / "site.png"
        page.screenshot(path=str(shot))
        status = page.inner_text("#status")
        # characters are counted as the server counts them: 300 emoji pass, 301 do not; a lone surrogate is refused
        text = [page.evaluate(f"window.smf.generate({{prompt: {p}, seconds: 2, seed: 1, footskate: 'off'}})"
                              ".then(() => '', (e) => e.message)")
                for p in ("'\\u{1F600}'.repeat(300)", "'\\u{1F600}'.repeat(301)", "'a \\uD800 walks'")]
        assert text[0] == "" and "at most 300 characters" in text[1] and "lone surrogate" in text[2], text
        browser.close()
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    want = pipe(PROMPT, seconds=4, seed=SEED, footskate="off")[0].joints
    got = np.asarray(joints)
    assert got.shape == want.shape and np.abs(got - want).max() < 5e-3
    assert np.abs(np.asarray(cleaned) - pipe(PROMPT, seconds=4, seed=SEED)[0].joints).max() < 5e-3
    assert "footskate" in bad  # one clear message
    names = list(HUMANML3D.joint_names)
    (tmp_path / "m.bvh").write_text(bvh)
    b = read_bvh(tmp_path / "m.bvh")
    assert np.abs(forward_kinematics(b)[:, [b.names.index(n) for n in names]] - want).max() < 1e-3
    (tmp_path / "m.glb").write_bytes(bytes(glb))
    node_names, times, pos = play_node_tree(tmp_path / "m.glb")
    assert len(times) == len(want) and np.abs(pos[:, [node_names.index(n) for n in names]] - want).max() < 1e-3
    tools = gltf_validator_dir()
    if tools is not None:
        (tmp_path / "validate.cjs").write_text(VALIDATE_JS)
        out = subprocess.run(["node", str(tmp_path / "validate.cjs"), str(tmp_path / "m.glb"),
                              str(tools / "node_modules" / "gltf-validator")], capture_output=True, text=True, timeout=120)
        report = json.loads(out.stdout)
        assert report["numErrors"] == 0 and report["numWarnings"] == 0, report["messages"][:5]
    assert not outside and not logs, (outside, logs)
    assert f"seed {SEED}" in status
    from PIL import Image

    image = np.asarray(Image.open(shot).convert("L"), dtype=float)
    assert (image[60:500] < 100).sum() > 200  # the figure's dark joints and bones are drawn over the light floor


def webgpu_build() -> Path | None:
    """The dist/ folder of the npm package onnxruntime-web of the page's version, where .ci/run installs it
    ($SMF_TOOLS), or None."""
    folder = Path(os.environ.get("SMF_TOOLS", Path.home() / ".cache" / "stablemofusion-tools"))
    dist = folder / "node_modules" / "onnxruntime-web" / "dist"
    return dist if (dist / WEBGPU_FILES[0]).is_file() else None


def serve(folder: Path):
    """python -m http.server on ``folder`` at a free loopback port: (process, url)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = subprocess.Popen([sys.executable, "-m", "http.server", str(port), "-b", "127.0.0.1", "-d", str(folder)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(100):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            break
        except OSError:
            time.sleep(0.05)
    return server, f"http://127.0.0.1:{port}/"


def test_the_page_runs_the_graphs_on_webgpu_where_its_build_was_added(tmp_path):
    """`smf site --webgpu DIST` adds ONNX Runtime Web's WebGPU build; ?backend=webgpu runs the graphs on WebGPU
    (here Chromium's software adapter, SwiftShader), the same motion within 5 mm; without an adapter, one clear
    message."""
    dist = webgpu_build()
    if dist is None:
        pytest.skip("the npm package onnxruntime-web is not installed in $SMF_TOOLS (.ci/run installs it)")
    assert main(["site", "--out", str(tmp_path / "site"), "--webgpu", str(dist)]) == 0
    server, url = serve(tmp_path / "site")
    webgpu = FLAGS + ["--enable-unsafe-webgpu", "--use-webgpu-adapter=swiftshader"]
    try:
        with playwright.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=webgpu)
            page = browser.new_page()
            page.goto(url + "?backend=webgpu", wait_until="load")
            if not page.evaluate("(async () => !!(navigator.gpu && await navigator.gpu.requestAdapter()))()"):
                browser.close()
                pytest.skip("this Chromium offers no software WebGPU adapter")
            joints = page.evaluate(f"window.smf.generate({{prompt: '{PROMPT}', seconds: 2, seed: {SEED}, "
                                   "footskate: 'off'}).then(() => window.smf.lastMotion.joints)")
            backend = page.evaluate("window.smf.timings.backend")
            browser.close()
            browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)  # no WebGPU at all
            page = browser.new_page()
            page.goto(url + "?backend=webgpu", wait_until="load")
            refused = page.evaluate("window.smf.ready.then(() => '', (e) => e.message)")
            browser.close()
    finally:
        server.terminate()
        server.wait(10)
    want = MotionPipeline.from_pretrained(backend="onnx", threads=1)(PROMPT, seconds=2, seed=SEED, footskate="off")[0].joints
    assert backend == "webgpu" and np.abs(np.asarray(joints) - want).max() < 5e-3
    assert "no WebGPU adapter" in refused


def test_a_site_without_the_webgpu_build_says_how_to_add_it(served):
    """The package ships no WebGPU build: ?backend=webgpu on a site written without it names the command."""
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        page = browser.new_page()
        page.goto(served + "?backend=webgpu", wait_until="load")
        refused = page.evaluate("window.smf.ready.then(() => '', (e) => e.message)")
        browser.close()
    assert "without ONNX Runtime Web's WebGPU build" in refused and "smf site --webgpu" in refused


def test_a_site_that_cannot_be_written_is_one_line_and_leaves_nothing(tmp_path, monkeypatch, capsys):
    """A full disk while the model is copied: one line naming the reason, exit 2, no half-written folder."""
    import errno

    import stablemofusion.serve.site as site

    def full(*_a, **_k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(site, "write_model", full)
    assert main(["site", "--out", str(tmp_path / "site")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("No space left on device") and len(err.splitlines()) == 1 and len(err) < 200, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_the_form_predicts_the_length_makes_sequences_part_by_part_and_names_downloads_after_the_prompt(served):
    """Seconds left empty by default (the length is predicted from the text, as the command line does), a prompt
    of several parts made part after part (the walk, then the wave: a wrist above its shoulder only in the wave's
    span) with the parts in the status line, and a download named after its prompt."""
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        page = browser.new_page(viewport={"width": 900, "height": 600})
        page.goto(served, wait_until="load")
        page.wait_for_function("!document.getElementById('generate').disabled", timeout=60_000)
        assert page.input_value("#seconds") == ""
        assert page.get_attribute("#seconds", "max") == "120"  # a prompt of several parts may be longer than a window
        page.fill("#prompt", "a tired man walks in a circle then waves")
        page.click("#generate")
        page.wait_for_function("window.smf.lastMotion && window.smf.lastMotion.prompt.includes('then waves')",
                               timeout=120_000)
        motion = page.evaluate("window.smf.lastMotion")
        assert [part for part, _ in motion["sequence"]] == ["a tired man walks in a circle", "a tired man waves"]
        assert "a tired man waves" in page.inner_text("#status") and "one after another" not in page.inner_text("#warning")
        joints = np.asarray(motion["joints"])
        cut = int(round(motion["sequence"][0][1] * motion["fps"]))
        assert len(joints) == cut + int(round(motion["sequence"][1][1] * motion["fps"])) > 80  # predicted lengths
        up = (joints[:, 20, 1] > joints[:, 16, 1]) | (joints[:, 21, 1] > joints[:, 17, 1])  # a wrist above its shoulder
        assert up[:cut].mean() < 0.1 and up[cut:].mean() > 0.5
        with page.expect_download() as download:
            page.click("#bvh")
        assert download.value.suggested_filename == "a_tired_man_walks_in_a_circle_then_waves.bvh"
        browser.close()
