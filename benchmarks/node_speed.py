"""The JavaScript runtime of a site folder (runtime/smf.js on the vendored ONNX Runtime Web, one WebAssembly
thread) timed in Node.js: 4 s motions of the plain prompts, footskate off and post interleaved call by call (the
order swapped each round, each prompt's text encoded by a first call), the best of the rounds per call; post / off,
and each round's ratio. Also each final-stage graph alone on one 4 s motion.

    python benchmarks/node_speed.py [--prompts 10] [--rounds 5]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import tempfile
from pathlib import Path

from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve.site import write_site

HERE = Path(__file__).resolve().parent

SCRIPT = r"""
import { join } from 'node:path';
import { pathToFileURL } from 'node:url';
const site = process.argv[2];
const { prompts, rounds } = JSON.parse(process.argv[3]);
const { loadRuntime } = await import(pathToFileURL(join(site, 'runtime', 'node.mjs')).href);
const rt = await loadRuntime(site);
for (const prompt of prompts) for (const fs of ['off', 'post']) await rt.generate({ prompt, seconds: 4, seed: 0, footskate: fs });
const best = { off: prompts.map(() => Infinity), post: prompts.map(() => Infinity) };
const perRound = [];
for (let r = 0; r < rounds; r++) {
  const took = { off: 0, post: 0 };
  for (let i = 0; i < prompts.length; i++) {
    for (const fs of ((r + i) % 2 === 0 ? ['off', 'post'] : ['post', 'off'])) {
      const t = performance.now();
      await rt.generate({ prompt: prompts[i], seconds: 4, seed: 1, footskate: fs });
      const dt = performance.now() - t;
      took[fs] += dt;
      best[fs][i] = Math.min(best[fs][i], dt);
    }
  }
  perRound.push(took.post / took.off);
}
const sum = (a) => a.reduce((x, y) => x + y, 0);
process.stdout.write(JSON.stringify({ off: sum(best.off) / prompts.length, post: sum(best.post) / prompts.length,
                                      perRound }));
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--prompts", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    node = shutil.which("node")
    if node is None:
        raise SystemExit("node_speed.py: Node.js is not installed (apt-get install nodejs)")
    prompts = [json.loads(x)["prompt"] for x in (HERE / "prompts_plain.jsonl").read_text().splitlines()
               if x.strip()][:args.prompts]
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    with tempfile.TemporaryDirectory() as tmp:
        site = write_site(Path(tmp) / "site", pipe.graphs)
        script = Path(tmp) / "bench.mjs"
        script.write_text(SCRIPT)
        run = subprocess.run([node, str(script), str(site), json.dumps({"prompts": prompts, "rounds": args.rounds})],
                             capture_output=True, text=True, timeout=3600)
    if run.returncode != 0:
        raise SystemExit(f"node_speed.py: {run.stderr.strip().splitlines()[-1]}")
    got = json.loads(run.stdout)
    print(json.dumps({"ms_per_motion_off": round(got["off"], 2), "ms_per_motion_post": round(got["post"], 2),
                      "post_over_off": round(got["post"] / got["off"], 3),
                      "post_over_off_each_round": [round(x, 3) for x in got["perRound"]]}, indent=1))


if __name__ == "__main__":
    main()
