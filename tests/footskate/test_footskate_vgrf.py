"""Distillation of the 22-joint vGRF student: a few steps on a tiny corpus, save/load, CLI and errors."""

import json

import numpy as np
import pytest
import torch

from stablemofusion.cli.main import main
from stablemofusion.core.errors import SMFError
from stablemofusion.footskate.vgrf import VgrfStudent, load_vgrf_model, save_vgrf_model


def test_save_load_roundtrip(tmp_path):
    torch.manual_seed(0)
    m = VgrfStudent().eval()
    save_vgrf_model(m, tmp_path / "v.safetensors", {"figures": {"x": 1}})
    meta = json.loads((tmp_path / "v.json").read_text())
    assert "non-commercial" in meta["licence"]
    back = load_vgrf_model(tmp_path / "v.safetensors")
    x = torch.randn(1, 30, 22, 3)
    assert torch.equal(m(x), back(x))
    assert (tmp_path / "v.safetensors").stat().st_size < 1_000_000


def test_load_errors(tmp_path):
    with pytest.raises(SMFError, match="not found"):
        load_vgrf_model(tmp_path / "none.safetensors")
    (tmp_path / "bad.safetensors").write_bytes(b"junk")
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(SMFError, match="not a distilled"):
        load_vgrf_model(tmp_path / "bad.safetensors")


def test_student_is_translation_invariant():
    torch.manual_seed(0)
    m = VgrfStudent().eval()
    x = torch.randn(1, 20, 22, 3)
    shifted = x + torch.tensor([3.0, 0.0, -2.0])
    assert torch.allclose(m(x), m(shifted), atol=1e-5)


def test_distil_cli_on_a_tiny_corpus(up_weights, wave, tmp_path, capsys):
    data = tmp_path / "corpus"
    (data / "new_joints").mkdir(parents=True)
    for i, k in enumerate((0, 20, 40)):
        np.save(data / "new_joints" / f"{i:06d}.npy", wave[k:k + 60])
    (data / "train.txt").write_text("000000\n000001\n")
    (data / "test.txt").write_text("000002\n")
    out = tmp_path / "v.safetensors"
    code = main(["footskate", "distil", "--underpressure", str(up_weights), "--data", str(data), "--out", str(out),
                 "--steps", "3"])
    assert code == 0, capsys.readouterr().err
    figures = json.loads(capsys.readouterr().out.splitlines()[-2])
    assert figures["train_motions"] == 2 and "val_foot_rmse" in figures
    assert load_vgrf_model(out)(torch.tensor(wave[None], dtype=torch.float32)).shape == (1, 118, 2, 16)
    assert main(["footskate", "distil", "--underpressure", str(tmp_path / "no.tar"), "--data", str(data),
                 "--out", str(out)]) == 2
