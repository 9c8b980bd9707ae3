"""`smf bench` on an untrained preset: it runs to the end and reports the end-to-end time per motion."""

import json

import numpy as np
import pytest
import torch

from stablemofusion.cli.bench import rest_features
from stablemofusion.cli.main import main
from stablemofusion.core.errors import SMFError
from stablemofusion.motion.features import bone_lengths, joints_from_features
from stablemofusion.motion.rigid import fit_rigid
from stablemofusion.motion.skeleton import HUMANML3D


def test_bench_of_an_untrained_preset_reports_end_to_end_time(tmp_path):
    torch.set_num_threads(1)
    out = tmp_path / "bench.json"
    assert main(["bench", "--preset", "small", "--steps", "2", "--batch-sizes", "1,2", "--repeats", "1",
                 "--frames", "40", "--engine", "fast", "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["results"]
    assert [r["batch_size"] for r in rows] == [1, 2]
    for r in rows:
        assert r["aits"] > 0 and r["final_stage_seconds_per_motion"] > 0
        assert r["end_to_end_seconds_per_motion"] > r["final_stage_seconds_per_motion"]


def test_an_untrained_preset_decodes_to_a_standing_body():
    """Its zero output is the normalisation mean: the rest pose on the dataset skeleton, not a point."""
    joints = joints_from_features(np.repeat(rest_features("humanml3d")[None], 3, axis=0))
    assert np.allclose(bone_lengths(joints)[:, 1:], np.asarray(HUMANML3D.bone_lengths)[1:], atol=1e-6)
    assert abs(joints[..., 1].min()) < 1e-6  # feet on the floor


def test_joints_on_one_point_are_a_clear_error_not_nan():
    with pytest.raises(SMFError, match="all sit on one point"):
        fit_rigid(np.zeros((4, 22, 3)))
