"""Release export: EMA weights only, float16, model card inside, loads back as a pipeline."""

import numpy as np
import torch
from safetensors.torch import load_file

from stablemofusion.cli.main import main
from stablemofusion.diffusion.checkpoint import EMA, MODEL, STATE, load_checkpoint, save_checkpoint
from stablemofusion.diffusion.config import CheckpointConfig
from stablemofusion.models.base import build_denoiser
from stablemofusion.models.presets import get_preset


def test_export_keeps_ema_weights_in_fp16(tmp_path, capsys):
    torch.manual_seed(0)
    cfg = get_preset("tiny")
    model = build_denoiser(cfg)
    ema = {k: v + 0.5 if v.is_floating_point() else v for k, v in model.state_dict().items()}
    src = tmp_path / "run" / "checkpoint"
    save_checkpoint(src, model=model, mean=np.zeros(263), std=np.ones(263), ema_state=ema, training_state={"step": 3},
                    config=CheckpointConfig.for_skeleton(cfg, step=3))
    card = tmp_path / "card.md"
    card.write_text("# card\nnon-commercial\n")
    out = tmp_path / "release"
    assert main(["export", "--checkpoint", str(tmp_path / "run"), "--out", str(out), "--card", str(card)]) == 0
    assert "MB" in capsys.readouterr().out
    assert (out / "MODEL_CARD.md").read_text() == card.read_text()
    assert not (out / EMA).exists() and not (out / STATE).exists()
    weights = load_file(out / MODEL)
    key = next(k for k, v in weights.items() if v.is_floating_point())
    assert weights[key].dtype == torch.float16
    torch.testing.assert_close(weights[key].float(), ema[key].half().float())
    ck = load_checkpoint(out)
    assert ck.config.export.from_step == 3
    assert main(["export", "--checkpoint", str(tmp_path / "nope"), "--out", str(out)]) == 2
