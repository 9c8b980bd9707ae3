"""Crafted adapter files: memory bombs, wrong ranks, shapes and types, non-finite values, huge scales, broken
metadata and containers. Each is small on disk; a loader that multiplied or read before checking would ask for
gigabytes. Used by the adapter tests and by benchmarks/faults.py.

    crafted_adapters(folder, checkpoint) -> {case: (path, words the refusal names)}
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import torch
from safetensors.torch import save_file

from stablemofusion.adapters.file import FORMAT, VERSION, AdapterInfo, weights_hash
from stablemofusion.adapters.lora import LoraConfig
from stablemofusion.diffusion.checkpoint import load_checkpoint, read_config


def _info(base: dict, lora: dict | None = None) -> dict:
    lora = lora or {"rank": 2, "alpha": 2.0, "text": True}
    return AdapterInfo(name="crafted", actions={"crafted": ["a person crafts"]}, clips=[("c.bvh", "a person crafts")],
                       licence="CC BY 4.0", base=base, lora=LoraConfig(**lora), guidance=2.5).to_dict()


def _save(path: Path, tensors: dict, info: dict | str | None, meta: dict | None = None) -> Path:
    metadata = {"format": FORMAT, "version": str(VERSION)}
    if info is not None:
        metadata["info"] = info if isinstance(info, str) else json.dumps(info)
    metadata.update(meta or {})
    save_file({k: v.contiguous() for k, v in tensors.items()}, str(path), metadata=metadata)
    return path


def crafted_adapters(folder: Path, checkpoint: Path) -> dict[str, tuple[Path, str]]:
    """Twenty-four crafted adapter files for the (student) model at ``checkpoint``, written into ``folder``: case name ->
    (path, a phrase its one-line refusal contains). Every file passes the base-model check where a real adapter
    would (it records the model's own weights hash), so only the checks of what it holds can refuse it."""
    folder.mkdir(parents=True, exist_ok=True)
    model = load_checkpoint(checkpoint).model
    part = "student" if read_config(checkpoint).student else "teacher"
    base = {part: weights_hash(checkpoint)}
    linear = next(n[: -len(".weight")] for n, p in model.named_parameters()
                  if p.ndim == 2 and n.endswith(".weight") and "out_proj" not in n)
    out, inp = model.get_parameter(linear + ".weight").shape
    norm = next(n[: -len(".weight")] for n, p in model.named_parameters() if p.ndim == 1 and n.endswith(".weight"))
    A, B = f"{part}/{linear}.lora_A.weight", f"{part}/{linear}.lora_B.weight"
    a, b = torch.randn(2, inp, dtype=torch.float16) * 0.01, torch.randn(out, 2, dtype=torch.float16) * 0.01
    info = _info(base)
    cases: dict[str, tuple[dict, object, dict | None, str]] = {
        # name: (tensors, info, extra metadata, words of the refusal)
        "bomb 40 GB": ({A: torch.zeros(1, 100_000, dtype=torch.float16), B: torch.zeros(100_000, 1, dtype=torch.float16)},
                       info, None, "do not fit"),
        "bomb 160 GB": ({A: torch.zeros(1, 400_000, dtype=torch.float16), B: torch.zeros(400_000, 1, dtype=torch.float16)},
                        info, None, "do not fit"),
        "rank over the layer": ({A: torch.zeros(4_000, inp, dtype=torch.float16), B: torch.zeros(out, 4_000, dtype=torch.float16)},
                                info, None, "do not fit"),
        "rank 0": ({A: a[:0], B: b[:, :0]}, info, None, "do not fit"),
        "1-D lora_A": ({A: a.flatten(), B: b}, info, None, "do not fit"),
        "3-D on a linear layer": ({A: a[..., None], B: b[..., None]}, info, None, "do not fit"),
        "wrong input width": ({A: torch.zeros(2, inp + 1, dtype=torch.float16), B: b}, info, None, "do not fit"),
        "wrong output width": ({A: a, B: torch.zeros(out + 1, 2, dtype=torch.float16)}, info, None, "do not fit"),
        "ranks differ": ({A: a, B: torch.zeros(out, 3, dtype=torch.float16)}, info, None, "do not fit"),
        "a layer the model lacks": ({f"{part}/no.such.layer.lora_A.weight": a, f"{part}/no.such.layer.lora_B.weight": b},
                                    info, None, "lacks"),
        "lora_B alone": ({B: b}, info, None, "no lora_A"),
        "lora_A alone": ({A: a}, info, None, "no lora_B"),
        "NaN": ({A: a * float("nan"), B: b}, info, None, "not finite"),
        "infinity": ({A: a, B: b * float("inf")}, info, None, "not finite"),
        "integer tensors": ({A: torch.ones(2, inp, dtype=torch.int64), B: torch.ones(out, 2, dtype=torch.int64)},
                            info, None, "not floating point"),
        "huge alpha": ({A: a, B: b}, _info(base, {"rank": 2, "alpha": 1e12, "text": True}), None, "scale"),
        "rank 0 in its info": ({A: a, B: b}, _info(base, {"rank": 2, "alpha": 2.0, "text": True}) | {"lora": {"rank": 0, "alpha": 2.0, "text": True}}, None, "rank is a whole number"),
        "info not JSON": ({A: a, B: b}, "{not json", None, "not a readable adapter file"),
        "info of the wrong kind": ({A: a, B: b}, json.dumps({**info, "clips": 5, "lora": "big"}), None,
                                   "not a readable adapter file"),
        "a tensor outside the parts": ({f"evil/{linear}.lora_A.weight": a}, info, None, "unexpected tensor"),
        "a layer whose weight is 1-D": ({f"{part}/{norm}.lora_A.weight": a, f"{part}/{norm}.lora_B.weight": b}, info,
                                        None, "is not one an adapter changes"),
        "info nested 100,000 deep": ({A: a, B: b}, "[" * 100_000 + "]" * 100_000, None, "not a readable adapter file"),
        "an alpha of 400 digits": ({A: a, B: b}, json.dumps({**info, "lora": {"rank": 2, "alpha": 10 ** 400}}), None,
                                   "alpha is a finite number"),
        "a name of the wrong kind": ({A: a, B: b}, json.dumps({**info, "name": ["x"]}), None, "name of the wrong kind"),
    }
    made = {}
    for k, (name, (tensors, meta_info, meta, words)) in enumerate(cases.items()):
        made[name] = (_save(folder / f"{k:02d}.safetensors", tensors, meta_info, meta), words)
    return made


def broken_containers(folder: Path) -> dict[str, tuple[Path, str]]:
    """Files that are not adapters at all: junk bytes, a header that claims 2**62 bytes, a 300 MB (sparse) file."""
    folder.mkdir(parents=True, exist_ok=True)
    junk = folder / "junk.safetensors"
    junk.write_bytes(b"\x00" * 100)
    header = folder / "header.safetensors"
    header.write_bytes(struct.pack("<Q", 1 << 62) + b"{}")
    huge = folder / "huge.safetensors"
    with open(huge, "wb") as f:
        f.truncate(300 * 2**20)
    return {"junk bytes": (junk, "not a readable adapter file"), "a header of 2**62 bytes": (header, "not a readable"),
            "a 300 MB file": (huge, "too large")}
