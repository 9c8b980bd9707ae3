"""The web viewer in a real headless Chromium (Debian's, driven by Playwright): loads without console errors,
a generate round trip draws the skeleton, scrubbing changes the pose, a dropped .npy is shown. Skipped where
Chromium or Playwright is absent (CI installs both)."""

from __future__ import annotations

import io
import shutil
import socket
import threading
import time
import urllib.error
import urllib.request

import numpy as np
import pytest
import torch

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
playwright = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (apt-get install chromium)")
FLAGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run"]


@pytest.fixture(scope="module")
def server(tmp_path_factory, save_tiny_checkpoint, save_random_adapter):
    """The app on a tiny random-weight checkpoint with an adapter ("kick") offered beside it, served by uvicorn on a
    free loopback port."""
    import uvicorn

    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.serve import create_app

    torch.set_num_threads(1)
    mean, std = np.zeros(263), np.full(263, 0.1)
    mean[3] = 0.9
    ck = save_tiny_checkpoint(tmp_path_factory.mktemp("viewer-ckpt") / "checkpoint", mean, std)
    pipe = MotionPipeline.from_pretrained(ck, device="cpu")
    pipe.add_variants([save_random_adapter(tmp_path_factory.mktemp("viewer-adapter") / "kick.safetensors", ck)])
    app = create_app(pipe)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{port}"
    # ready means the worker answers (health 200), not only the socket: on a loaded machine the worker starts late,
    # and the page's first health check would get a 503
    for _ in range(1200):
        try:
            with urllib.request.urlopen(url + "/v1/health", timeout=5) as r:
                if r.status == 200:
                    break
        except (OSError, urllib.error.HTTPError):
            pass
        time.sleep(0.05)
    yield url
    srv.should_exit = True
    thread.join(10)


@pytest.fixture(scope="module")
def page(server):
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        pg = browser.new_page(viewport={"width": 800, "height": 600})
        pg.logs = []
        pg.on("console", lambda m: pg.logs.append(f"{m.type}: {m.text}") if m.type in ("error", "warning") else None)
        pg.on("pageerror", lambda e: pg.logs.append(f"pageerror: {e}"))
        pg.goto(server + "/")
        yield pg
        browser.close()


def shot(page) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(page.locator("#view canvas").screenshot())).convert("RGB")).astype(int)


def bone_pixels(image: np.ndarray) -> int:
    """Pixels near the left (blue) or right (red) bone colours."""
    blue = np.abs(image - [0x1F, 0x77, 0xB4]).sum(-1) < 90
    red = np.abs(image - [0xD6, 0x27, 0x28]).sum(-1) < 90
    return int((blue | red).sum())


def generate_and_pause(page, frame: int, body: bool) -> None:
    """Generate 'a person walks forward' for 2 s (with or without the skinned body), pause at ``frame``."""
    page.set_checked("#body", body)
    page.fill("#prompt", "a person walks forward")
    page.fill("#seconds", "2")
    page.fill("#seed", "0")
    page.click("#generate")
    page.wait_for_function("window.smf.ready && (window.smf.character !== null) === " + str(body).lower(),
                           timeout=60_000)
    page.click("#play")  # pause
    page.evaluate(f"window.smf.setFrame({frame})")
    page.wait_for_timeout(200)


def test_generate_draws_the_skeleton_and_scrubbing_moves_it(page):
    page.wait_for_timeout(300)
    empty = shot(page)
    assert bone_pixels(empty) == 0
    page.select_option("#footskate", "off")
    generate_and_pause(page, 0, body=False)  # the skeleton alone
    first = shot(page)
    dark = lambda im: int((im.sum(-1) < 200).sum())  # noqa: E731  (the joints' spheres)
    assert bone_pixels(first) > 20 and dark(first) > dark(empty) + 100
    assert page.evaluate("window.smf.frames") == 40
    page.fill("#scrub", "35")
    page.dispatch_event("#scrub", "input")
    page.wait_for_timeout(200)
    assert page.evaluate("window.smf.frame") == 35
    later = shot(page)
    assert (np.abs(later - first).sum(-1) > 60).sum() > 50  # the pose changed on screen
    assert "frame 36 / 40" in page.inner_text("#frame")
    page.check("#body")
    assert page.logs == []


def test_a_timeline_prompt_and_an_empty_length(page):
    page.fill("#prompt", "a person walks:2; a person bows:1.5")
    page.click("#generate")
    page.wait_for_function("window.smf.ready && window.smf.frames === 70", timeout=60_000)
    assert "a person walks:2; a person bows:1.5" in page.inner_text("#status")
    page.fill("#prompt", "a person walks forward")
    page.fill("#seconds", "")  # no length: the model's estimate (this test model has none: 4 s)
    page.click("#generate")
    page.wait_for_function("window.smf.ready && window.smf.frames === 80", timeout=60_000)
    page.fill("#prompt", "walk:; bow:2")
    page.click("#generate")
    page.wait_for_function("document.getElementById('status').className === 'error'", timeout=30_000)
    assert "is not PROMPT:SECONDS" in page.inner_text("#status")
    assert [m for m in page.logs if "pageerror" in m] == []


def test_one_generation_per_click_the_servers_limits_and_a_fresh_seed(page, server):
    """A click with the body shown asks for JSON and then .glb: the server makes the motion once. The viewer caps
    nothing itself (30 s is a long motion, as at every door) and shows the server's refusal; an empty seed is a
    fresh one, shown with the motion."""
    import httpx

    batches = lambda: httpx.get(server + "/v1/health").json()["batches"]  # noqa: E731
    page.fill("#prompt", "a person walks forward")
    page.fill("#seed", "")
    page.fill("#seconds", "30")
    before = batches()
    page.set_checked("#body", True)
    page.click("#generate")
    page.wait_for_function("window.smf.ready && window.smf.character !== null && window.smf.frames === 600",
                           timeout=120_000)
    assert batches() == before + 1
    assert "seed " in page.inner_text("#status")
    page.fill("#seconds", "121")
    page.click("#generate")
    page.wait_for_function("document.getElementById('status').className === 'error'", timeout=30_000)
    assert "seconds must be more than 0 and at most 120 s" in page.inner_text("#status")
    page.fill("#seconds", "2")


def test_the_adapters_the_server_offers_can_be_chosen(page, server):
    """The menu lists the server's adapters; with one chosen, the motion is that adapter's (the server's answer
    to the same request with "adapter")."""
    import httpx

    assert page.eval_on_selector_all("#adapter option", "os => os.map((o) => o.textContent)") == ["base", "kick"]
    assert page.is_visible("#adapter")
    page.fill("#prompt", "a person kicks")
    page.fill("#seconds", "2")
    page.fill("#seed", "5")
    page.select_option("#footskate", "off")
    shown = {}
    for choice in ("kick", ""):
        page.select_option("#adapter", choice)
        page.evaluate("window.smf.ready = false")
        page.click("#generate")
        page.wait_for_function("window.smf.ready", timeout=60_000)
        shown[choice] = np.asarray(page.evaluate("Array.from(window.smf.joints)")).reshape(40, 22, 3)
    body = {"prompt": "a person kicks", "seconds": 2, "seed": 5, "footskate": "off"}
    kick = httpx.post(server + "/v1/generate", json={**body, "adapter": "kick"}).json()["joints"]
    base = httpx.post(server + "/v1/generate", json=body).json()["joints"]
    assert np.abs(shown["kick"] - np.asarray(kick)).max() < 1e-3
    assert np.abs(shown[""] - np.asarray(base)).max() < 1e-3
    assert np.abs(shown["kick"] - shown[""]).max() > 1e-2


def test_the_out_of_domain_warning_is_shown(page):
    """The server's warning of a prompt far from the model's actions is shown with the motion (the tiny test
    model knows no actions, so the answer is the server's for such a prompt, rewritten in the page's fetch)."""
    page.route("**/v1/generate", lambda route: route.fulfill(
        status=200, content_type="application/json",
        body=__import__("json").dumps({"prompt": "does a backflip", "fps": 20.0, "frames": 40, "seed": 3,
                                       "warning": "'does a backflip' is not like anything this model was trained on",
                                       "joints": np.zeros((40, 22, 3)).tolist()})))
    try:
        page.set_checked("#body", False)
        page.fill("#prompt", "does a backflip")
        page.click("#generate")
        page.wait_for_function("document.getElementById('status').className === 'error'", timeout=30_000)
        assert "Warning: 'does a backflip' is not like anything" in page.inner_text("#status")
    finally:
        page.unroute("**/v1/generate")


def test_the_answers_warnings_and_parts_are_shown(page):
    """Every warning of the answer, and how a prompt of several parts was split, are shown with the motion."""
    page.route("**/v1/generate", lambda route: route.fulfill(
        status=200, content_type="application/json",
        body=__import__("json").dumps({"prompt": "a man walks then waves", "fps": 20.0, "frames": 40, "seed": 3,
                                       "warnings": ["length 20 frames (1.00 s) clamped to 40 frames (2.00 s)"],
                                       "sequence": [{"prompt": "a man walks", "seconds": 1.0},
                                                    {"prompt": "a man waves", "seconds": 1.0}],
                                       "joints": np.zeros((40, 22, 3)).tolist()})))
    try:
        page.set_checked("#body", False)
        page.fill("#prompt", "a man walks then waves")
        page.click("#generate")
        page.wait_for_function("document.getElementById('status').className === 'error'", timeout=30_000)
        text = page.inner_text("#status")
        assert "Warning: length 20 frames (1.00 s) clamped" in text
        assert 'made part after part: "a man walks" 1.0 s, then "a man waves" 1.0 s' in text
        banner = page.locator("#warning")  # and in the banner above the view, where the user looks
        assert banner.is_visible() and "clamped to 40 frames" in banner.inner_text()
    finally:
        page.unroute("**/v1/generate")


def test_dropping_a_local_npy_shows_it_and_bad_files_show_an_error(page):
    from stablemofusion.motion.files import load_motion

    joints = load_motion("example:wave-both-hands").joints.astype(np.float32)
    buf = io.BytesIO()
    np.save(buf, joints)
    data = list(buf.getvalue())
    drop = """async ([name, bytes]) => {
        const dt = new DataTransfer();
        dt.items.add(new File([new Uint8Array(bytes)], name));
        window.dispatchEvent(new DragEvent('drop', {dataTransfer: dt, bubbles: true, cancelable: true}));
    }"""
    page.evaluate(drop, ["wave.npy", data])
    page.wait_for_function("window.smf.ready && window.smf.frames === 118", timeout=30_000)
    assert "wave.npy: 118 frames" in page.inner_text("#status")
    page.evaluate(drop, ["notes.txt", [104, 105]])
    page.wait_for_function("document.getElementById('status').className === 'error'", timeout=30_000)
    assert "only .bvh and .npy" in page.inner_text("#status")
    assert [m for m in page.logs if "pageerror" in m] == []


def test_the_character_glb_is_shown_in_step_with_the_skeleton(page, tmp_path):
    """The generated motion's .glb (GLTFLoader) plays in step with the JSON joints, and a dropped .glb plays too."""
    generate_and_pause(page, 25, body=True)
    glb = np.array(page.evaluate("window.smf.glbJoints(25)"))
    json_joints = np.array(page.evaluate("Array.from(window.smf.joints.subarray(25 * 66, 26 * 66))")).reshape(22, 3)
    assert np.abs(glb - json_joints).max() < 1e-3  # the glTF node tree gives the same joints (1 mm)
    with_body = shot(page)
    page.uncheck("#body")
    page.wait_for_timeout(200)
    assert (np.abs(with_body - shot(page)).sum(-1) > 60).sum() > 200  # the body was on screen
    page.check("#body")
    page.wait_for_timeout(200)
    assert not page.is_disabled("#glb")
    data = page.evaluate("""async () => {
        const res = await fetch('/v1/generate?format=glb', {method: 'POST', headers: {'Content-Type': 'application/json'},
            body: JSON.stringify({prompt: 'a person bows', seconds: 3, seed: 1})});
        return Array.from(new Uint8Array(await res.arrayBuffer()));
    }""")
    assert bytes(data[:4]) == b"glTF"
    page.evaluate("""async (bytes) => {
        const dt = new DataTransfer();
        dt.items.add(new File([new Uint8Array(bytes)], 'bow.glb'));
        window.dispatchEvent(new DragEvent('drop', {dataTransfer: dt, bubbles: true, cancelable: true}));
    }""", data)
    page.wait_for_function("window.smf.ready && window.smf.frames === 60", timeout=30_000)
    assert "bow.glb: 60 frames" in page.inner_text("#status")
    assert [m for m in page.logs if "pageerror" in m] == []


def test_live_mode_keeps_moving_and_a_new_prompt_changes_it(page, tmp_path):
    """Live: the character keeps moving on the WebSocket stream; a new prompt and Enter reach the server and
    its frames (the next prompt_index) are shown; unchecking live stops the stream and leaves it to scrub."""
    logs = len(page.logs)
    page.fill("#prompt", "a person walks forward")
    page.check("#live")
    page.wait_for_function("window.smf.live && window.smf.live.received >= 30", timeout=60_000)
    assert page.inner_text("#generate") == "Send"
    first, before = page.evaluate("window.smf.frame + window.smf.live.offset"), shot(page)
    # the play clock runs (as fast as frames arrive: a loaded machine may hold the newest frame a while)
    page.wait_for_function(f"window.smf.frame + window.smf.live.offset > {first} + 10", timeout=60_000)
    assert (np.abs(shot(page) - before).sum(-1) > 60).sum() > 50  # and the picture moves
    page.fill("#prompt", "a person waves both hands")
    page.press("#prompt", "Enter")
    page.wait_for_function("window.smf.live.index === 1", timeout=30_000)
    # the new prompt's frames on screen: waited for, not timed (a loaded machine delivers them late)
    page.wait_for_function("document.getElementById('status').textContent.includes('live: \"a person waves both hands\"')",
                           timeout=60_000)
    page.screenshot(path=str(tmp_path / "live.png"))
    page.evaluate("window.liveSocket = window.smf.live.ws")
    page.uncheck("#live")
    page.wait_for_function("window.smf.live === null && !document.getElementById('scrub').disabled", timeout=10_000)
    # frames still in flight when the stream stopped are dropped, not appended to a stream that is gone
    page.evaluate("window.liveSocket.dispatchEvent(new MessageEvent('message', {data: JSON.stringify("
                  "{type: 'frames', start: 0, fps: 20, prompt_index: 0, joints: [[[0, 0, 0]]]})}))")
    assert "live stream ended" in page.inner_text("#status")
    assert page.inner_text("#generate") == "Generate"
    assert page.logs[logs:] == []  # no error or warning while streaming


def test_a_live_stream_that_breaks_connects_again_and_continues_where_the_character_stands(page):
    """A live connection that breaks (as when its server dies behind a load balancer) is opened again with the same
    prompt and seed; the new stream's frames come after the old ones and start where the character stood."""
    logs = len(page.logs)
    page.fill("#prompt", "a person walks forward")
    page.fill("#seed", "3")
    page.check("#live")
    page.wait_for_function("window.smf.live && window.smf.live.received >= 30", timeout=60_000)
    page.evaluate("window.smf.live.ws.close(4000)")  # not a normal end (1000): the viewer connects again
    page.wait_for_function("window.smf.live && window.smf.live.reconnects === 1 && window.smf.live.place !== null "
                           "&& window.smf.live.received > window.smf.live.base + 20", timeout=60_000)
    base, offset = page.evaluate("[window.smf.live.base, window.smf.live.offset]")
    joints = np.asarray(page.evaluate("Array.from(window.smf.joints)"), dtype=np.float64).reshape(-1, 22, 3)
    seam = base - offset  # the first frame of the new stream
    assert np.abs(joints[seam, 0, [0, 2]] - joints[seam - 1, 0, [0, 2]]).max() < 1e-4  # the root goes on from there
    assert page.evaluate("window.smf.live.index") == 0 and "live:" in page.inner_text("#status")
    page.uncheck("#live")
    page.wait_for_function("window.smf.live === null", timeout=10_000)
    page.fill("#seed", "")
    assert page.logs[logs:] == []


def test_a_path_drawn_on_the_floor_is_followed(page):
    """Tick "path", click three points on the floor: the request carries them and the root passes each."""
    page.select_option("#footskate", "off")
    page.fill("#prompt", "a person walks forward")
    page.check("#draw")
    assert page.input_value("#seconds") == ""  # the path's own length
    box = page.locator("#view canvas").bounding_box()
    for fx, fy in ((0.5, 0.8), (0.5, 0.6), (0.35, 0.55)):  # the floor, in front of the default camera
        page.mouse.click(box["x"] + fx * box["width"], box["y"] + fy * box["height"])
    points = page.evaluate("window.smf.path.points")
    assert len(points) == 3 and page.is_visible("#clear-path")
    page.click("#generate")
    page.wait_for_function("window.smf.ready", timeout=60_000)
    joints = np.asarray(page.evaluate("Array.from(window.smf.joints)"), dtype=np.float64).reshape(-1, 22, 3)
    xz = joints[:, 0, [0, 2]]
    assert max(np.linalg.norm(xz - np.asarray(p), axis=-1).min() for p in points) < 0.3
    page.click("#clear-path")
    page.uncheck("#draw")
    assert page.evaluate("window.smf.path.points.length") == 0
    assert [m for m in page.logs if "pageerror" in m] == []


def test_the_footskate_menu_offers_what_the_server_runs(page, server):
    """Every mode on a PyTorch server; a server whose health lists only 'off' and 'post' (the portable runtime's)
    gets a menu without 'loop'."""
    import json

    shown = "os => os.filter((o) => !o.hidden).map((o) => o.value)"
    assert page.eval_on_selector_all("#footskate option", shown) == ["post", "off", "loop"]
    context = page.context.browser.new_context()
    other = context.new_page()

    def portable_health(route):
        health = route.fetch().json()
        health["limits"]["footskate"] = ["off", "post"]
        route.fulfill(status=200, content_type="application/json", body=json.dumps(health))

    other.route("**/v1/health", portable_health)
    other.goto(server + "/")
    other.wait_for_function("[...document.querySelectorAll('#footskate option')].some((o) => o.hidden)",
                            timeout=30_000)
    assert other.eval_on_selector_all("#footskate option", shown) == ["post", "off"]
    context.close()
