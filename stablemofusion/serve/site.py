"""The static site (`smf site --out DIR`): a page that generates motions in the browser with no server, on a model's
portable graphs (ONNX Runtime Web, WebAssembly), with the JavaScript runtime (``assets/runtime/smf.js``: tokenizer,
sampler table, seeded noise; the final stage runs as the package's graphs, ``assets/final_stage/``).

The folder holds the page (``index.html``, ``site.js``, ``site.css``), the JavaScript runtime (``runtime/``), the
vendored npm assets (``vendor/``: onnxruntime-web, @huggingface/tokenizers, three.js) and the model (``model/``: the
graphs the page runs, the tokenizer, the known actions' embeddings and ``web.json``, the model's description for
JavaScript). Any static file server can host it; it makes no request outside its own origin.
"""

from __future__ import annotations

import json
import re
import shutil
from importlib import resources
from pathlib import Path

import numpy as np

from ..core.errors import SMFError
from ..motion.bvh import BVH_ORDER
from ..motion.gltf import BODY_COLOUR, BONE_RADIUS, DEFAULT_RADIUS, HAND_LENGTH, HEAD_RADIUS
from ..core.path_plan import KINDS, MAX_PATH_METRES, MAX_PATH_SPEED, MAX_WAYPOINTS, MIN_TRAVEL
from ..core.language import language_lexicon
from ..core.reliability import WEAK_FLOOR, WEAK_MARGIN, graphs_reliability
from ..core.sequence_plan import sequence_lexicon
from ..core.timeline_plan import DEFAULT_OVERLAP, TAIL
from ..core.limits import LENGTH_MULTIPLE, MAX_PROMPT_CHARS, MAX_SECONDS
from ..core.noise import LENGTH_DRAW
from ..text.known import TAUGHT_MARGIN
from ..motion.rigid import DEFAULT_FIT
from ..motion.skeleton import get_skeleton

SITE_GRAPHS = ("text_encoder", "condition", "denoise", "length", "ood")  # what the page runs: the student's path
FINAL_STAGE = ("rigid", "bend", "follow", "contacts", "cleanup", "pose", "continue")  # and the final stage's graphs (the package's, any model: final_stage_graph)
# ONNX Runtime Web's WebGPU build (?backend=webgpu, 26.9 MB): not in the package; `smf site --webgpu DIR` copies it
# from the dist/ folder of the npm package onnxruntime-web of the version the package vendors (vendored_ort_web_version)
WEBGPU_FILES = ("ort.webgpu.min.mjs", "ort-wasm-simd-threaded.asyncify.mjs", "ort-wasm-simd-threaded.asyncify.wasm")
ORT_VENDOR = ("site", "vendor", "onnxruntime-web")
_ORT_BANNER = re.compile(r"ONNX Runtime Web v(\d+\.\d+\.\d+)")
MODEL_LICENCE = ("The model's weights were trained on Bandai-Namco motion capture (CC BY-NC 4.0): non-commercial "
                 "use only. MiniLM (the text encoder): Apache-2.0.")


def weak_actions(graphs) -> dict:
    """The actions the model draws badly (its folder's reliability table; none without one), with their clips and
    accuracy, the margin a prompt must be closer to one of them than to any action drawn well, and the floor: how
    close to it at least (core/reliability.py)."""
    table = graphs_reliability(graphs.folder) or {}
    weak = {a: {"clips": r.clips, "accuracy": r.accuracy} for a, r in table.items() if r.weak}
    return {"actions": weak, "margin": WEAK_MARGIN, "floor": WEAK_FLOOR}


def web_description(graphs) -> dict:
    """``web.json``: what the JavaScript runtime needs of a model's graphs (:class:`~stablemofusion.backends.onnx_graphs.
    PortableGraphs`): file names, frame rate and lengths, the default sampler's table, the normalisation, the
    skeleton's names, tree and bone lengths, the path words and the limits of a path, the known actions."""
    m, manifest = graphs.model, graphs.manifest
    if graphs.manifest.get("actions") is None or not graphs.has_length_model:
        raise SMFError("the site needs a model with a length model and known actions (the shipped model has both)")
    table = m.table(m.sampler, m.steps)
    sk = get_skeleton(m.entry["skeleton"])
    if sk.bone_lengths is None or DEFAULT_FIT.bone_lengths != "dataset" or DEFAULT_FIT.method != "sweeps":
        raise SMFError("the site's rigid stage (rigid.onnx) fits the skeleton's dataset bone lengths by block sweeps")
    actions = manifest["actions"]
    # an adapted model's actions ("taught") come after the base's, in the same arrays
    groups = list(actions["actions"].items()) + list((actions.get("taught") or {}).items())
    # a taught action's clip captions, each with its row among the examples: what a prompt clearly closest to the
    # action is answered with (text/known.py: DomainCheck.answer)
    starts = np.cumsum([0] + [len(examples) for _, examples in groups]).tolist()
    answers = {name: [[starts[g] + examples.index(c), c] for c in (actions.get("taught_clips") or {}).get(name, [])]
               for g, (name, examples) in enumerate(groups) if g >= len(actions["actions"])}
    return {
        "fps": m.fps, "min_frames": m.min_frames, "max_frames": m.max_frames, "length_multiple": LENGTH_MULTIPLE,
        "pad_multiple": m.pad_multiple, "motion_dim": m.dim, "guidance": m.guidance, "sampler": m.sampler,
        "steps": m.steps, "student": m.student, "max_tokens": graphs.max_tokens, "max_prompt_chars": MAX_PROMPT_CHARS,
        "table": {"t": table.t.tolist(), "c_in": table.c_in.tolist(), "a": table.a.tolist(), "b": table.b.tolist(),
                  "c": table.c.tolist(), "d": table.d.tolist(), "init_sigma": table.init_sigma,
                  "stochastic": table.stochastic},
        "mean": m.mean.astype(np.float64).tolist(), "std": m.std.astype(np.float64).tolist(),
        "skeleton": {"name": sk.name, "names": list(sk.joint_names), "parents": [int(p) for p in sk.parents],
                     "bone_lengths": list(sk.bone_lengths)},
        "length_draw": LENGTH_DRAW,  # the noise draw of a motion's length quantile (core/noise.py)
        "paths": path_lexicon(), "path_kinds": list(KINDS), "bvh_order": BVH_ORDER,
        # a prompt of several parts: split as core/sequence_plan.py splits it, made as a timeline (core/timeline_plan.py)
        "sequence": {**sequence_lexicon(), "overlap_frames": int(round(DEFAULT_OVERLAP * m.fps)), "tail": TAIL,
                     "max_seconds": MAX_SECONDS},
        "languages": language_lexicon(),  # the word lists that tell a prompt that is not English (core/language.py)
        "weak_actions": weak_actions(graphs),  # actions the model draws badly, and the margin (core/reliability.py)
        "glb_body": {"bone_radius": dict(BONE_RADIUS), "default_radius": DEFAULT_RADIUS, "head_radius": HEAD_RADIUS,
                     "hand_length": HAND_LENGTH, "colour": list(BODY_COLOUR[:3])},
        "path_limits": {"max_points": MAX_WAYPOINTS, "max_metres": MAX_PATH_METRES, "max_speed": MAX_PATH_SPEED,
                        "min_travel": MIN_TRAVEL},
        "actions": {"names": [name for name, _ in groups], "threshold": actions["threshold"], "top": int(actions["top"]),
                    "owner": [i for i, (_, examples) in enumerate(groups) for _ in examples],
                    "embeddings": "actions.bin", "taught_from": len(actions["actions"]),
                    "taught_similarity": actions.get("taught_similarity", 1.0),
                    "answers": {name: rows for name, rows in answers.items() if rows}, "taught_margin": TAUGHT_MARGIN},
        "tokenizer": "tokenizer.json",
        "files": {name: f"{name}.onnx" for name in SITE_GRAPHS + FINAL_STAGE}, "final_stage": list(FINAL_STAGE),
        "licence": MODEL_LICENCE,
    }


def path_lexicon() -> dict:
    """The path words' lexicon (``assets/lexicons/paths.json``) for the JavaScript runtime (``assets/runtime/paths.js``):
    its regular expressions in JavaScript's syntax (named groups ``(?<name>``)."""
    text = (resources.files("stablemofusion") / "assets" / "lexicons" / "paths.json").read_text("utf-8")
    return json.loads(text.replace("(?P<", "(?<"))


def final_stage_graph(name: str) -> Path:
    """The package's graph ``name`` (one of FINAL_STAGE) of the final stage (:func:`~stablemofusion.backends.onnx_export.
    export_final_stage`: the Python functions themselves, exported)."""
    return Path(str(resources.files("stablemofusion") / "assets" / "final_stage" / f"{name}.onnx"))


def _graph_file(graphs, name: str) -> Path:
    m = graphs.manifest
    where = {"text_encoder": m["text_encoder"]["file"], "condition": m["model"]["files"]["condition"],
             "denoise": m["model"]["files"]["denoise"], "length": m.get("length", {}).get("file"),
             "ood": (m.get("actions") or {}).get("detector")}[name]
    return graphs.folder / where


def write_model(graphs, out: Path) -> Path:
    """The ``model/`` folder of a site (also what Node.js reads): graphs, tokenizer, embeddings, ``web.json``."""
    out.mkdir(parents=True, exist_ok=True)
    info = web_description(graphs)
    for name in SITE_GRAPHS:
        shutil.copyfile(_graph_file(graphs, name), out / info["files"][name])
    for name in FINAL_STAGE:
        shutil.copyfile(final_stage_graph(name), out / info["files"][name])
    shutil.copyfile(graphs.folder / graphs.manifest["text_encoder"]["tokenizer"], out / info["tokenizer"])
    actions = graphs.manifest["actions"]
    emb = np.load(graphs.folder / actions["embeddings"]).astype("<f4")
    if actions.get("taught"):
        emb = np.concatenate([emb, np.load(graphs.folder / actions["taught_embeddings"]).astype("<f4")])
    (out / info["actions"]["embeddings"]).write_bytes(emb.tobytes())
    (out / "web.json").write_text(json.dumps(info), encoding="utf-8")
    (out / "LICENCE.txt").write_text(MODEL_LICENCE + "\n", encoding="utf-8")
    return out


def ort_web_version(path: Path) -> str | None:
    """The ONNX Runtime Web version named in the banner of a build's ``.mjs`` file, or None."""
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            found = _ORT_BANNER.search(f.read(4096))
    except OSError:
        return None
    return found.group(1) if found else None


def vendored_ort_web_version() -> str:
    """The version of ONNX Runtime Web the package vendors (its WebAssembly build)."""
    assets = Path(str(resources.files("stablemofusion") / "assets"))
    version = ort_web_version(assets.joinpath(*ORT_VENDOR) / "ort.wasm.min.mjs")
    if version is None:
        raise SMFError("this install's ONNX Runtime Web build names no version")
    return version


def check_webgpu_build(folder: Path) -> list[Path]:
    """The files of ONNX Runtime Web's WebGPU build in ``folder`` (the npm package's ``dist/``), checked: all there
    and of the vendored version. SMFError naming what is wrong and how to get it."""
    want = vendored_ort_web_version()
    how = f"the dist/ folder of `npm install onnxruntime-web@{want}`"
    if not folder.is_dir():
        raise SMFError(f"--webgpu {folder}: no such folder; give {how}")
    missing = [name for name in WEBGPU_FILES if not (folder / name).is_file()]
    if missing:
        raise SMFError(f"--webgpu {folder}: {', '.join(missing)} not there; give {how}")
    got = ort_web_version(folder / WEBGPU_FILES[0])
    if got != want:
        raise SMFError(f"--webgpu {folder}: ONNX Runtime Web {got or 'of no named version'}, the page runs {want}; "
                       f"give {how}")
    return [folder / name for name in WEBGPU_FILES]


def write_site(out: Path, graphs, webgpu: Path | None = None) -> Path:
    """The whole static folder at ``out`` (made anew: the folder must be absent or a site written before);
    ``webgpu``: a folder holding ONNX Runtime Web's WebGPU build (:func:`check_webgpu_build`), copied in so that
    ``?backend=webgpu`` runs; without it the page says how to add it."""
    assets = Path(str(resources.files("stablemofusion") / "assets"))
    if out.exists() and any(out.iterdir()) and not (out / "model" / "web.json").is_file():
        raise SMFError(f"{out} exists and is not a site written by `smf site`: choose an empty or new folder")
    build = [] if webgpu is None else check_webgpu_build(Path(webgpu))
    tmp = out.with_name(out.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        shutil.copytree(assets / "site", tmp, ignore=shutil.ignore_patterns("__pycache__"))
        shutil.copytree(assets / "runtime", tmp / "runtime")
        shutil.copytree(assets / "viewer" / "vendor", tmp / "vendor" / "three")
        for name in ("figure.js", "viewer.css"):  # the viewer's stick figure and style
            shutil.copyfile(assets / "viewer" / name, tmp / name)
        write_model(graphs, tmp / "model")
        for f in build:
            shutil.copyfile(f, tmp.joinpath(*ORT_VENDOR[1:]) / f.name)
    except OSError as e:  # a full disk, no permission: nothing half-written is left
        shutil.rmtree(tmp, ignore_errors=True)
        raise SMFError(f"could not write the site to {out}: {_first_reason(e)}") from None
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    return out


def _first_reason(e: OSError) -> str:
    """One line for a failed copy: copytree's error lists every file that failed; its first reason is enough."""
    if isinstance(e, shutil.Error) and e.args and isinstance(e.args[0], list) and e.args[0]:
        return str(e.args[0][0][-1]).splitlines()[0]
    return e.strerror or str(e).splitlines()[0]


def folder_size(path: Path) -> int:
    """Bytes of every file under ``path``."""
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


__all__ = ["FINAL_STAGE", "MODEL_LICENCE", "SITE_GRAPHS", "final_stage_graph", "WEBGPU_FILES", "check_webgpu_build", "folder_size",
           "ort_web_version", "vendored_ort_web_version", "web_description", "write_model", "write_site"]
