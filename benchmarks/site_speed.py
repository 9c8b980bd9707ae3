"""The static site (`smf site`) in Debian's headless Chromium, as a visitor meets it: time from opening the page to
the model loaded and to the first motion, then per motion (4 s, text encoding included: a new prompt each time)
with footskate post (the default) and off (and the same prompts post and off interleaved over --rounds rounds, their text cached), the bytes the page downloads and the folder's size; served by a plain
static server (no cross-origin isolation: one WebAssembly thread) and, with --isolated, by one that sets COOP/COEP
(threads); and the first motion's joints against the Python runtime's.

    python benchmarks/site_speed.py [--motions 20] [--rounds 5] [--isolated]
"""

from __future__ import annotations

import argparse
import functools
import json
import shutil
import tempfile
import threading
import time
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FLAGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run"]


PATH_PROMPTS = ["a man walks in a circle", "a person turns around", "a woman runs in a zigzag", "someone walks there and back",
                "a person curves to the left", "a man turns 45 degrees to the right"]


class Isolated(SimpleHTTPRequestHandler):
    def end_headers(self):
        self.send_header("Cross-Origin-Opener-Policy", "same-origin")
        self.send_header("Cross-Origin-Embedder-Policy", "require-corp")
        super().end_headers()

    def log_message(self, *args):
        pass


class Plain(SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--motions", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=5, help="rounds of the interleaved post/off comparison")
    ap.add_argument("--isolated", action="store_true", help="serve with COOP/COEP headers (WebAssembly threads)")
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    from stablemofusion.core.path_plan import parse_path
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.serve.site import folder_size, write_site

    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    prompts = [json.loads(line)["prompt"] for line in (HERE / "prompts_freeform.jsonl").read_text().splitlines()]
    prompts = prompts[:2 * args.motions + 1]  # every motion timed has a prompt of its own
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_site(Path(tmp) / "site", pipe.graphs)
        handler = functools.partial(Isolated if args.isolated else Plain, directory=str(folder))
        server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        url = f"http://127.0.0.1:{server.server_address[1]}/"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=shutil.which("chromium"), args=FLAGS)
            page = browser.new_page()
            sizes: list[int] = []
            page.on("response", lambda r: sizes.append(int(r.headers.get("content-length", 0))))
            t0 = time.perf_counter()
            page.goto(url, wait_until="load")
            page.evaluate("window.smf.ready")
            loaded = time.perf_counter() - t0
            first = page.evaluate(f"window.smf.generate({{prompt: {json.dumps(prompts[0])}, seconds: 4, seed: 0}})"
                                  ".then(m => m.joints)")
            to_first = time.perf_counter() - t0
            per = {fs: [page.evaluate(f"window.smf.generate({{prompt: {json.dumps(q)}, seconds: 4, seed: {i}, "
                                      f"footskate: '{fs}'}}).then(() => window.smf.timings.lastMotionMs)")
                        for i, q in enumerate(prompts[1 + k * args.motions:1 + (k + 1) * args.motions])]
                   for k, fs in enumerate(("post", "off"))}
            threads = page.evaluate("window.smf.timings.threads")
            # the cleanup's share: the same prompts (their encoding cached by a first call), post and off
            # interleaved call by call, the order swapped each round; each call's best over the rounds
            same = {"post": np.full(args.motions, np.inf), "off": np.full(args.motions, np.inf)}
            ratios = []
            for r in range(-1, args.rounds):
                took = {"post": 0.0, "off": 0.0}
                for i, q in enumerate(prompts[1:1 + args.motions]):
                    for fs in (("off", "post") if (r + i) % 2 == 0 else ("post", "off")):
                        ms = page.evaluate(f"window.smf.generate({{prompt: {json.dumps(q)}, seconds: 4, "
                                           f"seed: {i}, footskate: '{fs}'}}).then(() => "
                                           "window.smf.timings.lastMotionMs)")
                        if r >= 0:  # round -1 encodes each prompt's text
                            took[fs] += ms
                            same[fs][i] = min(same[fs][i], ms)
                if r >= 0:
                    ratios.append(round(took["post"] / took["off"], 3))
            # path prompts against the same prompts without their path words (what the model is given), same page
            pairs = [(q, parse_path(q).prompt) for q in PATH_PROMPTS]
            path_ms = {k: [] for k in ("path", "without")}
            for rep in range(3):
                for q, plain in pairs:
                    for k, text in (("path", q), ("without", plain)):
                        path_ms[k].append(page.evaluate(f"window.smf.generate({{prompt: {json.dumps(text)}, "
                                                        f"seconds: 4, seed: {rep}}}).then(() => window.smf.timings"
                                                        ".lastMotionMs)"))
            browser.close()
        server.shutdown()
        want = pipe(prompts[0], seconds=4, seed=0)[0].joints  # footskate post, as the page's default
        out = {"served": "COOP/COEP (isolated)" if args.isolated else "plain static server", "wasm_threads": threads,
               "page_to_model_loaded_s": round(loaded, 2), "page_to_first_motion_s": round(to_first, 2),
               "same_prompts_text_cached_best_ms_mean": {fs: round(float(np.mean(v)), 1) for fs, v in same.items()},
               "same_prompts_post_over_off": round(float(same["post"].sum() / same["off"].sum()), 3),
               "same_prompts_post_over_off_each_round": ratios,
               **{f"per_motion_ms_{fs}": {"median": round(float(np.median(v)), 1), "range": [round(min(v), 1),
                                                                                        round(max(v), 1)]}
                  for fs, v in per.items()}, "motions": len(per["post"]),
               "path_prompt_ms_median": round(float(np.median(path_ms["path"])), 1),
               "without_path_words_ms_median": round(float(np.median(path_ms["without"])), 1),
               "downloaded_MB": round(sum(sizes) / 1e6, 1), "folder_MB": round(folder_size(folder) / 1e6, 1),
               "max_joint_difference_mm": round(float(np.abs(np.asarray(first) - want).max()) * 1000, 4)}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
