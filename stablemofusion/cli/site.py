"""`smf site --out DIR [--checkpoint GRAPHS] [--webgpu ORT_DIST]`: a static folder that generates motions in the browser, with no server
(docs/site.md)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name, description="Write a static web page that generates motions in the browser (ONNX "
                                         "Runtime Web, WebAssembly): host the folder with any static file server; "
                                         "docs/site.md.")
    p.add_argument("--out", type=Path, required=True, help="folder to write (new, or a site written before)")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="a folder of portable graphs (smf export --onnx) or a model folder holding one (default: "
                        "the shipped model's)")
    p.add_argument("--webgpu", type=Path, default=None, metavar="ORT_DIST",
                   help="add ONNX Runtime Web's WebGPU build (26.9 MB, not in the package) for ?backend=webgpu: the "
                        "dist/ folder of `npm install onnxruntime-web@VERSION`, VERSION the one the page runs "
                        "(docs/site.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..pipelines.motion_pipeline import MotionPipeline
    from ..serve.site import folder_size, vendored_ort_web_version, write_site

    graphs = MotionPipeline.from_pretrained(args.checkpoint, backend="onnx").graphs
    out = write_site(args.out, graphs, args.webgpu)
    print(f"wrote {out} ({folder_size(out) / 1e6:.0f} MB): serve it with any static file server, for example "
          f"`python -m http.server -d {out}`, and open http://127.0.0.1:8000/")
    if args.webgpu is None:
        print(f"  the page runs on WebAssembly; for ?backend=webgpu add ONNX Runtime Web's WebGPU build: "
              f"npm install onnxruntime-web@{vendored_ort_web_version()}, then smf site --out {out} --webgpu "
              "node_modules/onnxruntime-web/dist")
