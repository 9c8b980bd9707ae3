"""CheckpointConfig: one typed config per checkpoint, round-trips through config.json, reads older layouts."""

import json

import pytest

from stablemofusion.diffusion.config import CheckpointConfig, TrainConfig
from stablemofusion.diffusion.schedule import ScheduleConfig
from stablemofusion.core.errors import SMFError
from stablemofusion.models.presets import get_preset
from stablemofusion.pipelines.motion_pipeline import default_model_path


def test_round_trips_through_json():
    cfg = CheckpointConfig.for_skeleton(get_preset("small-sentence"), "humanml3d", train=TrainConfig(steps=7, lr=1e-3),
                                        step=7, schedule=ScheduleConfig(num_train_timesteps=500))
    back = CheckpointConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert back.to_dict() == json.loads(json.dumps(cfg.to_dict()))
    assert back.train.lr == 1e-3 and back.schedule.num_train_timesteps == 500 and back.step == 7
    assert back.guidance is None and "guidance" not in cfg.to_dict()  # configs without one stay as they were
    tuned = CheckpointConfig.from_dict({**cfg.to_dict(), "guidance": 1})
    assert tuned.guidance == 1.0 and CheckpointConfig.from_dict(json.loads(json.dumps(tuned.to_dict()))).guidance == 1.0


def test_frame_rate_and_length_range_come_from_the_skeleton():
    kit = CheckpointConfig.for_skeleton(get_preset("tiny", motion_dim=251), "kit")
    assert (kit.fps, kit.min_frames, kit.max_frames) == (12.5, 24, 196)
    # a config written without them (older layout) gets the skeleton's, not HumanML3D's 20 fps
    d = kit.to_dict()
    for k in ("fps", "min_frames", "max_frames", "schedule"):
        d.pop(k)
    back = CheckpointConfig.from_dict(d)
    assert (back.fps, back.min_frames, back.schedule) == (12.5, 24, ScheduleConfig())


def test_reads_the_shipped_model_config():
    """The shipped model's config.json (the schedule inside the training settings) reads as it was trained."""
    path = default_model_path()
    cfg = CheckpointConfig.from_dict(json.loads((path / "config.json").read_text()))
    assert cfg.model.arch == "unet" and cfg.model.text.sentence and cfg.fps == 20.0
    assert cfg.export.dtype == "float16" and cfg.train.preset == "small-sentence"
    assert cfg.schedule == cfg.train.schedule


@pytest.mark.parametrize("bad, msg", [
    ({"model": {"arch": "unet"}, "frames_per_second": 20}, "unknown config field"),
    ({"model": "unet"}, "needs an object 'model'"),
    ({"model": {"arch": "unet"}, "train": {"learning_rate": 1}}, "unknown config field"),
    ({"model": {"arch": "unet"}, "skeleton": "horse"}, "horse"),
    ({"model": {"arch": "unet"}, "train": "x"}, "'train' must be an object"),
    ({"model": {"arch": "unet"}, "fps": "abc"}, "bad checkpoint config"),
    ({"model": {"arch": "unet"}, "max_frames": 0}, "min_frames <= max_frames"),
    ({"model": {"arch": "unet"}, "guidance": -1}, "'guidance' must be a finite number >= 0"),
    ({"model": {"arch": "unet"}, "guidance": "2.5"}, "'guidance' must be a finite number >= 0"),
    ({"model": {"arch": "unet"}, "guidance": True}, "'guidance' must be a finite number >= 0"),
])
def test_bad_configs_are_one_line_errors(bad, msg):
    with pytest.raises(SMFError, match=msg):
        CheckpointConfig.from_dict(bad)


def test_resume_checks_only_what_must_match():
    base = CheckpointConfig.for_skeleton(get_preset("tiny"), train=TrainConfig(preset="tiny", steps=10))
    longer = CheckpointConfig.for_skeleton(get_preset("tiny"), train=TrainConfig(preset="tiny", steps=99, lr=1e-3,
                                                                                  checkpoint_every=3))
    assert longer.resume_mismatch(base) == []
    other = CheckpointConfig.for_skeleton(get_preset("small"), train=TrainConfig(preset="small", feat_bias=2.0))
    assert other.resume_mismatch(base) == ["model", "feat_bias"]
