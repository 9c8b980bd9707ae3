"""An adapter file's description and its checks, without PyTorch: what every door (``smf generate``, ``smf serve``,
``smf export``, the library) runs on a file before anything is loaded or multiplied.

:func:`read_header` reads the container (size, metadata, each tensor's name, shape and dtype; no tensor data);
:func:`fit_layers` checks the lora_A/lora_B pairs against a model's weight shapes; :func:`check_adapter_files` does
both and checks the values are finite, for a model folder whose weight shapes :func:`model_weight_shapes` reads from
its weights file's header or its portable graphs' manifest. A crafted file is refused in one line before PyTorch is
imported; :mod:`stablemofusion.adapters.lora` runs the same :func:`fit_layers` on the loaded tensors.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..core.folders import graphs_of, is_student, resolve, teacher_folder
from ..core.errors import SMFError

FORMAT = "stablemofusion-adapter"
VERSION = 1
MAX_ADAPTER_BYTES = 64 * 2**20  # a larger file is not an adapter of the models this package runs (rank 16 of the shipped one: 2.6 MB)
PARTS = ("student", "teacher")
FLOAT_DTYPES = ("F16", "BF16", "F32")  # safetensors' names of the dtypes an adapter's weights may have
MAX_SCALE = 1e3  # alpha / rank of an adapter: trained ones are about 1-2; beyond this the merged model is noise
LORA_A, LORA_B = ".lora_A.weight", ".lora_B.weight"


def _finite_number(x) -> bool:
    try:
        return math.isfinite(float(x))
    except (OverflowError, ValueError, TypeError):
        return False


def _strings(x) -> bool:
    return isinstance(x, list) and all(isinstance(v, str) for v in x)


@dataclass(frozen=True)
class LoraConfig:
    """Rank and scale of the low-rank updates (``alpha / rank`` multiplies B @ A); ``text``: the trainable text
    transformer's layers too (else the denoiser's only)."""

    rank: int = 16
    alpha: float = 16.0
    text: bool = True

    def __post_init__(self):
        if isinstance(self.rank, bool) or not isinstance(self.rank, int) or self.rank < 1:
            raise SMFError(f"an adapter's rank is a whole number from 1, got {self.rank!r}")
        if isinstance(self.alpha, bool) or not isinstance(self.alpha, (int, float)) or not _finite_number(self.alpha):
            raise SMFError(f"an adapter's alpha is a finite number, got {str(self.alpha)[:20]}")
        if not isinstance(self.text, bool):
            raise SMFError(f"an adapter's text flag is true or false, got {self.text!r}")

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def scale(self) -> float:
        return self.alpha / self.rank


@dataclass
class AdapterInfo:
    """What an adapter is: ``actions`` label -> the captions it was taught (the out-of-domain check knows
    them); ``clips`` (file, caption) pairs; ``base`` part -> sha256 of the base weights it fits;
    ``guidance`` the student's guidance scale it was distilled at; ``training`` figures of the run."""

    name: str
    actions: dict[str, list[str]]
    clips: list[tuple[str, str]]
    licence: str
    base: dict[str, str]
    lora: LoraConfig
    guidance: float | None = None
    training: dict = field(default_factory=dict)

    def __post_init__(self):
        ok = {"name": isinstance(self.name, str) and 0 < len(self.name) <= 200,
              "licence": isinstance(self.licence, str),
              "actions": isinstance(self.actions, dict) and all(isinstance(k, str) and _strings(v)
                                                                for k, v in self.actions.items()),
              "clips": isinstance(self.clips, list) and all(isinstance(c, (list, tuple)) and len(c) == 2
                                                            and _strings(list(c)) for c in self.clips),
              "base": isinstance(self.base, dict) and all(isinstance(k, str) and isinstance(v, str)
                                                          for k, v in self.base.items()),
              "lora": isinstance(self.lora, LoraConfig),
              "guidance": self.guidance is None or (not isinstance(self.guidance, bool)
                                                    and isinstance(self.guidance, (int, float))
                                                    and _finite_number(self.guidance)),
              "training": isinstance(self.training, dict)}
        bad = [k for k, v in ok.items() if not v]
        if bad:
            raise SMFError(f"an adapter's info has a {bad[0]} of the wrong kind")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["clips"] = [list(c) for c in self.clips]
        return d

    @staticmethod
    def from_dict(d: dict) -> "AdapterInfo":
        d = dict(d)
        d["lora"] = LoraConfig(**d["lora"])
        d["clips"] = [tuple(c) if isinstance(c, (list, tuple)) else c for c in d["clips"]]
        return AdapterInfo(**d)


def read_header(path: str | Path) -> tuple[AdapterInfo, dict[str, dict[str, tuple[tuple[int, ...], str]]]]:
    """(info, part -> {layer tensor name -> (shape, safetensors dtype)}) of an adapter file, no tensor data read; a
    one-line SMFError for anything that is not one (missing, over :data:`MAX_ADAPTER_BYTES`, not safetensors, another
    format or a newer version, broken info, a tensor outside the parts or not floating point)."""
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    if not path.is_file():
        raise SMFError(f"no such adapter file: {path}")
    if path.stat().st_size > MAX_ADAPTER_BYTES:
        raise SMFError(f"{path}: {path.stat().st_size / 2**20:.0f} MB is too large for an adapter")
    try:
        with safe_open(str(path), framework="numpy") as f:
            meta = f.metadata() or {}
            if meta.get("format") != FORMAT:
                raise SMFError(f"{path}: not a stablemofusion adapter (make one with `smf adapt`)")
            if int(meta.get("version", 0)) > VERSION:
                raise SMFError(f"{path}: adapter format {meta['version']} is newer than this version reads")
            try:
                info = AdapterInfo.from_dict(json.loads(meta["info"]))
            except SMFError as e:
                raise SMFError(f"{path}: {e}") from None
            except Exception as e:  # noqa: BLE001 - crafted JSON raises many types (deep nesting, huge numbers)
                raise SMFError(f"{path}: not a readable adapter file (its info: {type(e).__name__})") from None
            tensors: dict[str, dict] = {p: {} for p in PARTS}
            for key in f.keys():
                part, _, name = key.partition("/")
                if part not in tensors:
                    raise SMFError(f"{path}: unexpected tensor {key}")
                s = f.get_slice(key)
                if s.get_dtype() not in FLOAT_DTYPES:
                    raise SMFError(f"{path}: tensor {key} is {s.get_dtype()}, not floating point")
                tensors[part][name] = (tuple(s.get_shape()), s.get_dtype())
    except (SafetensorError, OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise SMFError(f"{path}: not a readable adapter file ({str(e).splitlines()[0]})") from None
    return info, tensors


def fit_layers(shapes: dict[str, tuple], scale: float, model_shapes: dict[str, tuple]) -> list[tuple[str, str, str]]:
    """``(layer, lora_A name, lora_B name)`` of each adapted layer of an adapter part whose tensors have ``shapes``
    (name -> shape), each pair checked against the model's weight shapes ``model_shapes`` (parameter name -> shape):
    one-line SMFError for a scale beyond :data:`MAX_SCALE`, a tensor that is neither, an unpaired one, a layer the
    model lacks, or a rank, shape or dimension that does not fit. What passes, merged, asks for no more memory than
    the model's own weights."""
    if not (math.isfinite(scale) and abs(scale) <= MAX_SCALE):
        raise SMFError(f"adapter scale (alpha / rank) must be finite and at most {MAX_SCALE:g}, got {scale:g}")
    pairs = []
    for key in shapes:
        if not key.endswith(LORA_A):
            if not key.endswith(LORA_B):
                raise SMFError(f"adapter tensor {key} is neither a lora_A nor a lora_B weight")
            if key[: -len(LORA_B)] + LORA_A not in shapes:
                raise SMFError(f"adapter layer {key[: -len(LORA_B)]} has lora_B but no lora_A")
            continue
        layer = key[: -len(LORA_A)]
        if layer + LORA_B not in shapes:
            raise SMFError(f"adapter layer {layer} has lora_A but no lora_B")
        a, b = tuple(shapes[key]), tuple(shapes[layer + LORA_B])
        want = model_shapes.get(layer + ".weight")
        if want is None:
            raise SMFError(f"the adapter changes {layer}.weight, which this model lacks (an adapter fits only the base "
                           "model it was trained on)")
        want = tuple(want)
        if len(want) not in (2, 3):
            raise SMFError(f"adapter layer {layer}: its weight {want} is not one an adapter changes (a linear or 1-D "
                           "convolution layer's)")
        fits = (len(want) == 2 and len(a) == 2 and len(b) == 2 and 1 <= a[0] == b[1] and a[1] == want[1]
                and b[0] == want[0]) or \
               (len(want) == 3 and len(a) == 3 and len(b) == 3 and 1 <= a[0] == b[1] and b[2] == 1
                and a[1:] == want[1:] and b[0] == want[0])
        if not fits or a[0] > min(want[0], want[1]):
            raise SMFError(f"adapter layer {layer}: lora_A {a} and lora_B {b} do not fit its weight {want} at a rank "
                           f"from 1 to {min(want[0], want[1])}")
        pairs.append((layer, key, layer + LORA_B))
    return pairs


def model_weight_shapes(folder: str | Path) -> dict[str, tuple[int, ...]] | None:
    """A model folder's weight shapes (parameter name -> shape) from its weights file's header (its EMA weights if
    it has them), or from its portable graphs' manifest where its weights are held there (the shipped model, and its
    teacher inside it); None where neither is there (the PyTorch checks run when it loads)."""
    from safetensors import SafetensorError, safe_open

    folder = resolve(folder)
    for name in ("ema.safetensors", "model.safetensors"):
        if (folder / name).is_file():
            try:
                with safe_open(str(folder / name), framework="numpy") as f:
                    return {k: tuple(f.get_slice(k).get_shape()) for k in f.keys()}
            except (SafetensorError, OSError):
                return None
    found = graphs_of(folder)
    if found is None:
        return None
    try:
        return {k: tuple(int(n) for n in w[3]) for k, w in found[1]["weights"].items()}
    except (ValueError, KeyError, TypeError, IndexError, AttributeError):
        return None


def _finite(f, key: str, dtype: str) -> bool:
    """Whether a float16 or float32 tensor holds finite values only (bfloat16, which numpy lacks, is checked by the
    PyTorch loader)."""
    return dtype == "BF16" or bool(np.isfinite(f.get_tensor(key)).all())


def model_part(folder: str | Path) -> str:
    """Which part of an adapter fits the model in ``folder``: "student" for a distilled student (its config names
    what it was distilled from), else "teacher"."""
    return "student" if is_student(folder) else "teacher"


def teacher_of(folder: str | Path) -> Path | None:
    """The folder of the teacher a distilled student in ``folder`` names, where it is there; else None."""
    try:
        return teacher_folder(folder)
    except SMFError:
        return None


def check_adapter_files(paths, folder: str | Path, part: str | None = None) -> list[AdapterInfo]:
    """Each adapter file of ``paths`` checked against the model in ``folder`` (its ``part``, student or teacher;
    default :func:`model_part`) without PyTorch: the container (:func:`read_header`), its ``part``'s layers against the model's weight shapes
    (:func:`fit_layers`, where :func:`model_weight_shapes` finds them) and finite values, one tensor at a time. The
    infos; one-line SMFError for the first problem. Whether it was trained on this very model (its weights' hash) is
    checked when the model loads."""
    from safetensors import safe_open

    paths = [paths] if isinstance(paths, (str, Path)) else list(paths or [])
    part = part or model_part(folder)
    model_shapes = model_weight_shapes(folder)
    infos = []
    for path in paths:
        info, tensors = read_header(path)
        if not tensors.get(part):
            raise SMFError(f"adapter {info.name!r} has no {part} weights")
        if model_shapes is not None:
            fit_layers({k: s for k, (s, _) in tensors[part].items()}, info.lora.scale, model_shapes)
        with safe_open(str(path), framework="numpy") as f:
            for name, (_, dtype) in tensors[part].items():
                if not _finite(f, f"{part}/{name}", dtype):
                    layer = name.rsplit(".lora_", 1)[0]
                    raise SMFError(f"adapter layer {layer} holds values that are not finite")
        infos.append(info)
    return infos


__all__ = ["AdapterInfo", "FORMAT", "LoraConfig", "MAX_ADAPTER_BYTES", "MAX_SCALE", "check_adapter_files",
           "fit_layers", "model_part", "model_weight_shapes", "read_header", "teacher_of"]
