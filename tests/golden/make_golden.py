"""Store the outputs of the shipped default pair for fixed seeds: tests/golden/test_golden.py compares the current
code's outputs to them (regenerate when the shipped weights or a seeded output change on purpose; docs/history.md
says when they did). The teacher (``default_model/teacher``, selected explicitly with ``teacher=True``:
SDE-DPM-Solver++ 2M Karras, 10 steps, its default guidance) on every task (text to motion, footskate post, a
timeline, every edit mode, x_t imputation, the HTTP response), and the student (``default_model``: lcm, 1 step;
edits at STUDENT_EDIT_STEPS) on a few, the HTTP response's joints included (keys ``student/...``). Both with the
default rigid stage; keys ``t2m_cfg_*`` are the teacher at guidance 2.5.

    OMP_NUM_THREADS=1 python tests/golden/make_golden.py   # writes tests/golden/golden.npz
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
EDITS = {  # mode -> keyword arguments of the edit (seconds)
    "prefix": dict(keep_start=1.0, seconds=4.0),
    "suffix": dict(keep_end=1.0, seconds=4.0),
    "inbetween": dict(keep_start=1.0, keep_end=1.0),
    "upper-body": dict(),
    "lower-body": dict(),
    "trajectory": dict(),
}
PROMPTS = ["a person walks forward", "someone jumps up and down"]
TIMELINE = [("a person walks forward", 3.0), ("a person turns around", 3.0), ("a person waves", 6.0)]


def project(features: np.ndarray) -> np.ndarray:
    """Features (T, D) -> (T, 8) float32 on 8 fixed random directions (a compact, sensitive fingerprint)."""
    rng = np.random.default_rng(0)
    return (np.asarray(features, dtype=np.float64) @ rng.standard_normal((features.shape[1], 8))).astype(np.float32)


def source_motion():
    """The shipped example motion as features (T, D)."""
    from stablemofusion.motion.features import features_from_joints
    from stablemofusion.motion.files import load_motion

    return features_from_joints(load_motion("example:wave-both-hands").joints)


def outputs(pipe) -> dict[str, np.ndarray]:
    """Every stored output of the teacher, named, in float32 (features and joints of each motion)."""
    out = {}

    def put(name, r):
        out[name + "/features"] = project(r.features)
        out[name + "/joints"] = np.asarray(r.joints, dtype=np.float32)

    for r, name in zip(pipe(PROMPTS, seconds=[2.0, 3.0], seed=[3, 7], footskate="off"), ("t2m_a", "t2m_b")):
        put(name, r)
    put("t2m_batch_seed", pipe(PROMPTS, seconds=2.0, seed=11, footskate="off")[1])
    put("t2m_post", pipe(PROMPTS[0], seconds=2.0, seed=5, footskate="post")[0])
    put("timeline", pipe.timeline(TIMELINE, seed=4, footskate="off"))
    src = source_motion()
    for mode, kw in EDITS.items():
        put(f"edit_{mode}", pipe.edit("a person waves", src, mode, seed=9, footskate="off", **kw))
    put("edit_prefix_xt", pipe.edit("a person waves", src, "prefix", seed=9, impose="xt", keep_start=1.0,
                                    seconds=4.0, footskate="off"))
    # classifier-free guidance on the real weights (the teacher's default 1.0 has no unconditional pass)
    for r, name in zip(pipe(PROMPTS, seconds=[2.0, 3.0], seed=[3, 7], guidance_scale=2.5, footskate="off"),
                       ("t2m_cfg_a", "t2m_cfg_b")):
        put(name, r)
    return out


def student_outputs(pipe) -> dict[str, np.ndarray]:
    """A few outputs of the student (keys ``student/...``): text to motion, a timeline, a prefix edit."""
    out = {}

    def put(name, r):
        out["student/" + name + "/features"] = project(r.features)
        out["student/" + name + "/joints"] = np.asarray(r.joints, dtype=np.float32)

    put("t2m_a", pipe(PROMPTS, seconds=[2.0, 3.0], seed=[3, 7], footskate="off")[0])
    put("t2m_post", pipe(PROMPTS[0], seconds=2.0, seed=5, footskate="post")[0])
    put("timeline", pipe.timeline(TIMELINE, seed=4, footskate="off"))
    put("edit_prefix", pipe.edit("a person waves", source_motion(), "prefix", seed=9, keep_start=1.0, seconds=4.0,
                                  footskate="off"))
    return out


def http_body(**pipeline_kwargs) -> dict:
    """The JSON body of POST /v1/generate (FastAPI TestClient, a thread executor)."""
    from fastapi.testclient import TestClient

    from stablemofusion.pipelines.motion_pipeline import MotionPipeline
    from stablemofusion.serve.app import create_app

    pipe = MotionPipeline.from_pretrained(device="cpu", **pipeline_kwargs)
    # the server checks the Host header (loopback names); the request as any local client sends it
    with TestClient(create_app(pipe), base_url="http://127.0.0.1") as client:
        res = client.post("/v1/generate", json={"prompt": "a person walks forward", "seconds": 2.0, "seed": 3,
                                                  "footskate": "off"})
        assert res.status_code == 200, res.text
        return res.json()


def main() -> None:
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    torch.set_num_threads(1)
    arrays = outputs(MotionPipeline.from_pretrained(teacher=True, device="cpu"))
    arrays.update(student_outputs(MotionPipeline.from_pretrained(device="cpu")))
    body = http_body(teacher=True)
    arrays["http/joints"] = np.asarray(body.pop("joints"), dtype=np.float32)
    for made_by in ("smf_version", "model_version"):  # not golden: they move with each version
        body.pop(made_by)
    arrays["http/meta"] = np.frombuffer(json.dumps(body, sort_keys=True).encode(), dtype=np.uint8)
    arrays["student/http/joints"] = np.asarray(http_body()["joints"], dtype=np.float32)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    (HERE / "golden.npz").write_bytes(buf.getvalue())
    print(f"wrote {len(arrays)} arrays, {len(buf.getvalue()) // 1024} KB")


if __name__ == "__main__":
    main()
