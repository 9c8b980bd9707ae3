"""Low-rank updates: the merged plain model computes what the wrapped one does; the adapter file round-trips."""

from __future__ import annotations

import pytest
import torch

from stablemofusion.adapters.file import Adapter, load_adapters
from stablemofusion.adapters.lora import (LoraConfig, add_lora, layer_deltas, lora_state, merge_into, no_fast_path,
                                          target_layers)
from stablemofusion.diffusion.checkpoint import load_checkpoint
from stablemofusion.core.errors import SMFError


def _random_lora(model: torch.nn.Module, seed: int = 1) -> None:
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in model.named_parameters():
            if "lora_" in name:
                p.copy_(torch.randn(p.shape, generator=g) * 0.05)


def _inputs(model, B: int = 3, T: int = 24):
    g = torch.Generator().manual_seed(0)
    x = torch.randn(B, T, 263, generator=g)
    t = torch.tensor([10, 500, 990])
    tokens = torch.randn(B, 5, model.text_config.in_dim, generator=g)
    tmask = torch.ones(B, 5, dtype=torch.bool)
    mask = torch.ones(B, T, dtype=torch.bool)
    mask[1, 20:] = False
    return x, t, tokens, tmask, torch.zeros(B, dtype=torch.bool), mask


def test_merged_weights_compute_what_the_wrapped_model_does(tiny_checkpoint):
    wrapped = load_checkpoint(tiny_checkpoint).model
    plain = load_checkpoint(tiny_checkpoint).model
    layers = target_layers(wrapped)
    assert any(isinstance(m, torch.nn.Conv1d) for n, m in wrapped.named_modules() if n in layers)
    assert not any(n.endswith("self_attn.out_proj") for n in layers)
    cfg = LoraConfig(rank=4, alpha=8.0)
    add_lora(wrapped, cfg)
    _random_lora(wrapped)
    state = lora_state(wrapped)
    assert {k.rsplit(".lora_", 1)[0] for k in state} == set(layers)
    with torch.no_grad(), no_fast_path():  # the wrapped model as it trains (its text layers through the wrappers)
        want = wrapped.eval()(*_inputs(wrapped))
        before = plain.eval()(*_inputs(plain))
        merge_into(plain, layer_deltas(state, cfg.scale, {n: tuple(p.shape) for n, p in plain.named_parameters()}))
        got = plain(*_inputs(plain))
    assert (want - before).abs().max() > 1e-3  # the updates change the output
    torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-5)


def test_new_lora_layers_leave_the_model_unchanged_and_train_only_themselves(tiny_checkpoint):
    model = load_checkpoint(tiny_checkpoint).model.eval()
    with torch.no_grad():
        before = model(*_inputs(model))
    add_lora(model, LoraConfig(rank=2))
    with torch.no_grad():
        after = model(*_inputs(model))
    torch.testing.assert_close(after, before)
    trainable = [n for n, p in model.named_parameters() if p.requires_grad]
    assert trainable and all("lora_" in n for n in trainable)


def test_adapter_file_round_trips_and_checks_its_base(tiny_checkpoint, save_random_adapter, tmp_path):
    path = save_random_adapter(tmp_path / "kick.safetensors", tiny_checkpoint)
    b = Adapter.load(path)
    assert b.info.name == "kick" and b.info.licence == "CC BY 4.0" and b.info.lora == LoraConfig(rank=2)
    assert all(v.dtype == torch.float32 and v.abs().max() > 0 for v in b.weights["teacher"].values())
    b.save(tmp_path / "again.safetensors")
    c = Adapter.load(tmp_path / "again.safetensors")
    assert c.info == b.info
    for k, v in b.weights["teacher"].items():
        torch.testing.assert_close(c.weights["teacher"][k], v, rtol=0, atol=0)  # float16 values round-trip
    b.check_base("teacher", tiny_checkpoint)  # the weights it was made on
    with pytest.raises(SMFError, match="another base model"):
        b.check_base("student", tiny_checkpoint)
    with pytest.raises(SMFError, match="no student weights"):
        b.deltas("student", {})


def test_bad_adapter_files_are_one_line_errors(tiny_checkpoint, save_random_adapter, tmp_path):
    from safetensors.torch import save_file

    with pytest.raises(SMFError, match="no such adapter file"):
        Adapter.load(tmp_path / "absent.safetensors")
    (tmp_path / "junk.safetensors").write_bytes(b"\x00" * 100)
    with pytest.raises(SMFError, match="not a readable adapter file"):
        Adapter.load(tmp_path / "junk.safetensors")
    save_file({"w": torch.zeros(2)}, str(tmp_path / "other.safetensors"))
    with pytest.raises(SMFError, match="not a stablemofusion adapter"):
        Adapter.load(tmp_path / "other.safetensors")
    a = save_random_adapter(tmp_path / "a.safetensors", tiny_checkpoint)
    with pytest.raises(SMFError, match="share a name"):
        load_adapters([a, a])


def test_crafted_adapters_are_refused_before_any_weight_is_multiplied(tiny_checkpoint, save_random_adapter, tmp_path):
    """A small file whose lora_B @ lora_A would be a huge matrix, a rank of 0, a 1-D tensor, a wrong shape, NaN or a
    huge scale: one-line SMFError from the checks against the model's weight shapes, before any product (the
    first case would be a 40 GB matrix)."""
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    pipe = MotionPipeline.from_pretrained(tiny_checkpoint, device="cpu")
    good = Adapter.load(save_random_adapter(tmp_path / "a.safetensors", tiny_checkpoint))
    part = next(p for p in good.weights if good.weights[p])
    layer = next(k[: -len(".lora_A.weight")] for k in good.weights[part] if k.endswith(".lora_A.weight"))
    a, b = good.weights[part][layer + ".lora_A.weight"], good.weights[part][layer + ".lora_B.weight"]
    cases = {
        "do not fit": {layer + ".lora_A.weight": torch.zeros(1, 100_000), layer + ".lora_B.weight": torch.zeros(100_000, 1)},
        "rank from 1": {layer + ".lora_A.weight": a[:0], layer + ".lora_B.weight": b[:, :0]},
        "not fit": {layer + ".lora_A.weight": a.flatten(), layer + ".lora_B.weight": b},
        "lacks": {"no.such.layer.lora_A.weight": a, "no.such.layer.lora_B.weight": b},
        "not finite": {layer + ".lora_A.weight": a * float("nan"), layer + ".lora_B.weight": b},
        "lora_B but no lora_A": {layer + ".lora_B.weight": b},
    }
    shapes = {n: tuple(p.shape) for n, p in pipe.model.named_parameters()}
    for why, weights in cases.items():
        with pytest.raises(SMFError, match=why):
            Adapter(good.info, {**good.weights, part: weights}).deltas(part, shapes)
    with pytest.raises(SMFError, match="scale"):
        layer_deltas(good.weights[part], 1e9, shapes)
    assert layer_deltas(good.weights[part], good.info.lora.scale, shapes)  # the genuine file still loads


def test_info_prints_an_adapters_text_escaped(tiny_checkpoint, save_random_adapter, tmp_path, capsys):
    """`smf info --adapter`: a caption or licence holding an ANSI escape is printed as text, never as the byte."""
    from dataclasses import replace

    from stablemofusion.cli.main import main

    good = Adapter.load(save_random_adapter(tmp_path / "kick.safetensors", tiny_checkpoint))
    info = replace(good.info, actions={"kick": ["a person \x1b[31mkicks"]}, licence="CC BY 4.0\x1b[2J")
    path = Adapter(info, good.weights).save(tmp_path / "escaped.safetensors")
    assert main(["info", "--adapter", str(path)]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out and "a person \\x1b[31mkicks" in out and "CC BY 4.0\\x1b[2J" in out


def test_every_crafted_file_is_refused_in_one_line_naming_its_problem(tiny_checkpoint, tmp_path):
    """Twenty-four crafted files and three broken containers (tests/adapters/crafted.py), each recording the model's own
    hash: refused by the check every door runs before the model loads, each naming what is wrong."""
    from crafted import broken_containers, crafted_adapters

    from stablemofusion.adapters.file import checked_adapters

    files = {**crafted_adapters(tmp_path / "crafted", tiny_checkpoint), **broken_containers(tmp_path / "broken")}
    assert len(files) == 27
    for case, (path, words) in files.items():
        with pytest.raises(SMFError, match=words) as e:
            checked_adapters([path], tiny_checkpoint)
        assert "\n" not in str(e.value), case


def test_the_command_line_and_a_server_refuse_a_crafted_file_before_loading_the_model(tiny_checkpoint, tmp_path):
    """`smf generate --adapter` and `smf serve --adapter` with a bomb (its product a 40 GB matrix) and with a rank of 0
    in its metadata, NaN values: exit 2, one line, the server never listens, and PyTorch was not imported (the check
    runs before it, in a few tens of MB)."""
    import socket
    import subprocess
    import sys

    from crafted import crafted_adapters

    files = crafted_adapters(tmp_path / "crafted", tiny_checkpoint)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = str(s.getsockname()[1])
    smf = ("import sys; from stablemofusion.cli.main import main; code = main(); "
           "print('torch imported:', 'torch' in sys.modules); sys.exit(code)")
    for case in ("bomb 40 GB", "rank 0 in its info", "NaN"):
        path, words = files[case]
        for args in (["generate", "a person walks", "--out", str(tmp_path / "out")],
                     ["serve", "--host", "127.0.0.1", "--port", port]):
            r = subprocess.run([sys.executable, "-c", smf, *args, "--checkpoint", str(tiny_checkpoint),
                                "--adapter", str(path)], capture_output=True, text=True, timeout=120)
            assert r.returncode == 2 and words in r.stderr, (case, args[0], r.stderr)
            assert len(r.stderr.strip().splitlines()) == 1, r.stderr
            assert "torch imported: False" in r.stdout, (case, args[0])
    assert not (tmp_path / "out").exists()
