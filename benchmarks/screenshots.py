"""Screenshots for the docs, of the real thing: the viewer of `smf serve` (the shipped model, ONNX backend) and the
static page of `smf site` (its JavaScript runtime) in Debian's headless Chromium, each showing a prompt of two parts
and a prompt with a warning (French; an action the model draws badly).

    python benchmarks/screenshots.py [--out docs/images]
"""

from __future__ import annotations

import argparse
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve import create_app
from stablemofusion.serve.site import write_site

FLAGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run"]
SHOTS = {"viewer-sequence.png": "a tired man walks in a circle then waves",
         "viewer-warning.png": "un homme marche lentement vers la porte"}
PAGE_SHOTS = {"page-sequence.png": "a tired man walks in a circle then waves",
              "page-warning.png": "a person kicks with the right leg"}


def shoot(page, url: str, shots: dict[str, str], out: Path) -> None:
    """Each prompt generated with seed 0 on the form at ``url``, the screenshot taken once the status names the
    motion."""
    page.goto(url)
    for name, prompt in shots.items():
        page.wait_for_function("!document.getElementById('generate').disabled", timeout=120_000)
        page.fill("#prompt", prompt)
        page.fill("#seed", "0")
        before = page.inner_text("#status")
        page.click("#generate")
        page.wait_for_function("([before]) => { const s = document.getElementById('status').textContent; "
                               "return s.includes('frames') && s !== before; }", arg=[before], timeout=120_000)
        page.wait_for_timeout(1500)
        page.screenshot(path=str(out / name))
        print(f"wrote {out / name}: {page.inner_text('#status')}")


def main() -> None:
    import uvicorn
    from playwright.sync_api import sync_playwright

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "images")
    args = ap.parse_args()
    app = create_app(MotionPipeline.from_pretrained(backend="onnx", threads=1), max_streams=0)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    threading.Thread(target=server.run, daemon=True).start()
    url = f"http://127.0.0.1:{port}"
    for _ in range(600):
        try:
            if urllib.request.urlopen(url + "/v1/health", timeout=5).status == 200:
                break
        except OSError:
            time.sleep(0.1)
    site = Path(tempfile.mkdtemp()) / "site"
    write_site(site, MotionPipeline.from_pretrained(backend="onnx", threads=1).graphs)
    static = subprocess.Popen([sys.executable, "-u", "-m", "http.server", "0", "-b", "127.0.0.1", "-d", str(site)],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    page_url = re.search(r"port (\d+)", static.stdout.readline())
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=shutil.which("chromium"), args=FLAGS)
        page = browser.new_page(viewport={"width": 900, "height": 620})
        shoot(page, url + "/", SHOTS, args.out)
        shoot(page, f"http://127.0.0.1:{page_url.group(1)}/", PAGE_SHOTS, args.out)
        browser.close()
    static.terminate()
    server.should_exit = True


if __name__ == "__main__":
    main()
