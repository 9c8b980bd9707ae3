"""`smf serve`'s API on a tiny random-weight checkpoint: formats, errors, limits, dynamic batching."""

from __future__ import annotations

import asyncio
import io

import httpx
import numpy as np
import pytest

from stablemofusion.core.noise import length_level
from stablemofusion.cli.main import main
from stablemofusion.motion.bvh import forward_kinematics, read_bvh
from stablemofusion.motion.skeleton import HUMANML3D
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.serve import create_app

from serve_helpers import OCTETS, call


def wait_until_ready(app, seconds: float = 120.0) -> dict:
    """Poll /v1/health until the worker is ready (bounded); returns the last health body."""
    import time

    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        (r,) = call(app, ("GET", "/v1/health", None))
        if r.status_code == 200:
            return r.json()
        time.sleep(0.1)
    raise AssertionError(f"not ready after {seconds} s: {r.json()}")


def test_health_and_json_generation(pipe):
    app = create_app(pipe)
    (gen,) = call(app, ("POST", "/v1/generate", {"prompt": "a person walks", "seconds": 2.4, "seed": 5, "steps": 2}))
    (health,) = call(app, ("GET", "/v1/health", None))
    assert health.status_code == 200 and health.json()["status"] == "ok"
    assert health.json()["worker"]["model_loaded"] and health.json()["worker"]["warm"]
    body = gen.json()
    assert gen.status_code == 200 and body["frames"] == 48 and body["fps"] == 20.0 and body["seed"] == 5
    joints = np.asarray(body["joints"])
    assert joints.shape == (48, 22, 3)
    lengths = np.linalg.norm(joints[:, 1:] - joints[:, list(HUMANML3D.parents[1:])], axis=-1)
    assert np.abs(lengths - np.asarray(HUMANML3D.bone_lengths[1:])).max() < 1e-4  # the rigid body


def test_bvh_and_npy_formats_are_the_same_motion(pipe, tmp_path):
    app = create_app(pipe)
    req = {"prompt": "a person walks", "seconds": 2.0, "seed": 1, "steps": 2}
    js, npy, bvh = call(app, ("POST", "/v1/generate", req), ("POST", "/v1/generate?format=npy", req),
                        ("POST", "/v1/generate?format=bvh", req))
    joints = np.asarray(js.json()["joints"])
    arr = np.load(io.BytesIO(npy.content), allow_pickle=False)
    assert npy.headers["content-type"] == "application/octet-stream" and arr.shape == (40, 22, 3)
    assert np.abs(arr - joints).max() < 1e-4
    (tmp_path / "m.bvh").write_text(bvh.text)
    b = read_bvh(tmp_path / "m.bvh")
    order = [b.names.index(n) for n in HUMANML3D.joint_names]
    assert np.abs(forward_kinematics(b)[:, order] - arr).max() < 1e-3


@pytest.mark.parametrize("url, body, status, message", [
    ("/v1/generate", {"prompt": "   "}, 422, "prompt must be a non-empty text"),
    ("/v1/generate", {"prompt": "x" * 301}, 422, "prompt must have at most 300 characters"),
    ("/v1/generate", {"prompt": "walk", "seconds": 121}, 422, "seconds must be more than 0 and at most 120 s"),
    ("/v1/generate", {"prompt": "walk", "seconds": 0}, 422, "seconds must be more than 0"),
    ("/v1/generate", {"prompt": "walk", "steps": 0}, 422, "steps"),
    ("/v1/generate", {"prompt": "walk", "seed": -1}, 422, "seed must be"),
    ("/v1/generate", {"prompt": "walk", "footskate": "maybe"}, 422, "footskate"),
    ("/v1/generate", {"prompt": "walk", "colour": "red"}, 422, "colour"),
    ("/v1/generate", {"seconds": 3}, 422, "prompt"),
    ("/v1/generate?format=fbx", {"prompt": "walk"}, 400, "format must be one of"),
    ("/v1/nothing", {"prompt": "walk"}, 404, "no such endpoint"),
])
def test_bad_requests_get_one_line_json_errors(pipe, url, body, status, message):
    (r,) = call(create_app(pipe), ("POST", url, body))
    assert r.status_code == status
    err = r.json()["error"]
    assert message in err and "\n" not in err


def test_a_body_that_is_not_json(pipe):
    async def go():
        transport = httpx.ASGITransport(app=create_app(pipe))
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
            return await client.post("/v1/generate", content=b"not json", headers={"Content-Type": "application/json"})
    r = asyncio.run(go())
    assert r.status_code == 422 and r.json() == {"error": "body: not valid JSON"}


def test_body_size_limit_and_full_queue(pipe):
    (r,) = call(create_app(pipe, max_body_bytes=100), ("POST", "/v1/generate", {"prompt": "x" * 200}))
    assert r.status_code == 413 and "larger than 100 bytes" in r.json()["error"]
    app = create_app(pipe, max_queue=1, wait_ms=50)
    reqs = [("POST", "/v1/generate", {"prompt": "walk", "seconds": 2, "seed": i, "steps": 1}) for i in range(4)]
    answers = sorted(call(app, *reqs), key=lambda r: r.status_code)
    assert answers[0].status_code == 200 and answers[-1].status_code == 503
    assert int(answers[-1].headers["retry-after"]) >= 1 and "busy" in answers[-1].json()["error"]
    (health,) = call(app, ("GET", "/v1/health", None))
    queue = health.json()["queue"]
    assert queue["refused"] >= 1 and queue["max_queued_cost"] > 0 and not queue["saturated"]


def test_a_lane_queues_four_of_the_largest_requests_the_server_takes(pipe):
    """The work each queue lane holds follows --max-request-cost: a server that takes larger requests still queues
    some of them (the default: four of 2,000 units)."""
    from stablemofusion.serve.server_limits import MAX_QUEUED_COST, QUEUED_REQUESTS

    assert create_app(pipe).state.batcher.max_queued_cost == MAX_QUEUED_COST == QUEUED_REQUESTS * 2000.0
    assert create_app(pipe, max_request_cost=1e6).state.batcher.max_queued_cost == QUEUED_REQUESTS * 1e6
    assert create_app(pipe, max_request_cost=1e6, max_queued_cost=5.0).state.batcher.max_queued_cost == 5.0


def batched_equals_alone(app, pipe, reqs, steps=2):
    """Send (action, seconds, seed) requests at once: they form one batch, and each motion equals the pipeline's
    for that request alone. Returns the responses."""
    out = call(app, *[("POST", "/v1/generate", {"prompt": f"a person {p}", "seconds": s, "seed": k, "steps": steps})
                      for p, s, k in reqs])
    assert app.state.batcher.batch_sizes == [len(reqs)]
    for r, (p, s, k) in zip(out, reqs):
        alone = pipe([f"a person {p}"], seconds=s, seed=[k], steps=steps)[0]
        assert np.abs(np.asarray(r.json()["joints"]) - alone.joints).max() < 1e-4
    return out


def test_dynamic_batching_gathers_requests_and_matches_generating_alone(pipe):
    """Concurrent requests share one sampling call, and each gets the motion it would get alone."""
    app = create_app(pipe, wait_ms=200)
    out = batched_equals_alone(app, pipe, [("walks", 2.0, 3), ("jumps", 3.2, 7), ("waves", 2.4, 11), ("walks", 2.0, 3)])
    assert np.array_equal(out[0].json()["joints"], out[3].json()["joints"])  # same request, same motion


def test_a_worker_process_generates_the_same_motions(pipe, checkpoint):
    """`smf serve` generates in a worker process that loads the checkpoint itself: same batching, same motions."""
    from stablemofusion.serve import ProcessWorker, ServedModel, WorkerSpec

    worker = ProcessWorker(WorkerSpec(str(checkpoint), "cpu", threads=1), ServedModel.of(pipe))
    app = create_app(worker, wait_ms=300)
    try:
        worker.start()
        wait_until_ready(app)
        batched_equals_alone(app, pipe, [("walks", 2.0, 3), ("jumps", 3.2, 7)])
    finally:
        app.state.batcher.close()
        worker.close()


def test_serve_cli_rejects_a_bad_port(capsys):
    assert main(["serve", "--port", "0"]) == 2
    assert "--port" in capsys.readouterr().err


def test_viewer_page_and_convert(pipe, tmp_path):
    from stablemofusion.motion.files import load_motion, save_bvh

    app = create_app(pipe)
    joints = load_motion("example:wave-both-hands").joints
    buf = io.BytesIO()
    np.save(buf, joints.astype(np.float32))
    save_bvh(joints, tmp_path / "w.bvh")
    pickled = io.BytesIO()
    np.save(pickled, np.array([{"a": 1}], dtype=object), allow_pickle=True)

    async def go():
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1", headers=OCTETS) as c:
            return await asyncio.gather(
                c.get("/"), c.get("/viewer/vendor/three.module.js"), c.get("/viewer/viewer.js"),
                c.post("/v1/convert?filename=w.npy", content=buf.getvalue()),
                c.post("/v1/convert?filename=w.bvh", content=(tmp_path / "w.bvh").read_bytes()),
                c.post("/v1/convert?filename=w.txt", content=b"hi"),
                c.post("/v1/convert?filename=p.npy", content=pickled.getvalue()),
                c.post("/v1/convert?filename=x.npy", content=b"not a numpy file"))
    page, three, js, npy, bvh, txt, pick, junk = asyncio.run(go())
    assert page.status_code == 200 and "importmap" in page.text and "/viewer/vendor/three.module.js" in page.text
    assert three.status_code == 200 and "REVISION" in three.text and js.status_code == 200
    assert npy.status_code == 200 and np.abs(np.asarray(npy.json()["joints"]) - joints).max() < 1e-4
    assert bvh.status_code == 200 and np.abs(np.asarray(bvh.json()["joints"]) - joints).max() < 1e-3
    assert txt.status_code == 415 and "only .bvh and .npy" in txt.json()["error"]
    for r in (pick, junk):  # never unpickled; one-line error naming the file
        assert r.status_code == 422 and "\n" not in r.json()["error"] and ".npy" in r.json()["error"]


def test_generate_reports_the_out_of_domain_check(checkpoint, tmp_path):
    import json as _json
    import shutil

    from stablemofusion.data.lexicon import known_actions, load_lexicon

    folder = tmp_path / "ck"
    shutil.copytree(checkpoint, folder)
    (folder / "actions.json").write_text(_json.dumps(known_actions(load_lexicon("bandai"), 0.56)))
    app = create_app(MotionPipeline.from_pretrained(folder, device="cpu"))
    ood, ok = call(app, ("POST", "/v1/generate", {"prompt": "does a backflip", "seconds": 2, "seed": 0, "steps": 2}),
                   ("POST", "/v1/generate", {"prompt": "a person walks forward", "seconds": 2, "seed": 0, "steps": 2}))
    a, b = ood.json(), ok.json()
    assert ood.status_code == 200 and a["out_of_domain"] is True and "backflip" in a["warning"]
    assert b["out_of_domain"] is False and "warning" not in b and b["closest_actions"][0][0] == "walk"
    assert 0 < a["similarity"] < 0.56 <= b["similarity"]


def test_generate_without_seconds_predicts_the_length(checkpoint, tmp_path):
    import shutil

    from stablemofusion.pipelines.motion_pipeline import default_model_path

    folder = tmp_path / "ck"
    shutil.copytree(checkpoint, folder)
    plain = create_app(MotionPipeline.from_pretrained(folder, device="cpu"))
    (r,) = call(plain, ("POST", "/v1/generate", {"prompt": "a person walks forward", "seed": 0, "steps": 1}))
    assert r.status_code == 200 and r.json()["frames"] == 80  # no estimator: 4 s
    for name in ("length.safetensors", "length.json"):  # the shipped estimator (same text encoder)
        shutil.copy(default_model_path() / name, folder / name)
    pipe = MotionPipeline.from_pretrained(folder, device="cpu")
    app = create_app(pipe)
    walk, hands = call(app, ("POST", "/v1/generate", {"prompt": "a person walks forward", "seed": 0, "steps": 1}),
                       ("POST", "/v1/generate", {"prompt": "a person raises both hands", "seed": 0, "steps": 1}))
    # each request its own seed: its length the quantile of stream 0 of seed 0
    expected = [int(round(s * 20)) // 4 * 4 for s in pipe.backend.predict_seconds(
        ["a person walks forward", "a person raises both hands"], [length_level(0)] * 2)]
    assert [walk.json()["frames"], hands.json()["frames"]] == expected and expected[0] > expected[1]


def test_timeline_endpoint(pipe):
    ok, bvh, bad_total, bad_empty, bad_prompt = call(
        create_app(pipe),
        ("POST", "/v1/timeline", {"segments": [{"prompt": "a person walks", "seconds": 3},
                                               {"prompt": "a person bows", "seconds": 2}], "seed": 1, "steps": 1}),
        ("POST", "/v1/timeline?format=bvh", {"segments": [{"prompt": "walk", "seconds": 2.5}], "seed": 1, "steps": 1}),
        ("POST", "/v1/timeline", {"segments": [{"prompt": "walk", "seconds": 100}, {"prompt": "run", "seconds": 30}]}),
        ("POST", "/v1/timeline", {"segments": []}),
        ("POST", "/v1/timeline", {"segments": [{"prompt": " ", "seconds": 2}]}))
    assert ok.status_code == 200 and ok.json()["frames"] == 100 and ok.json()["seed"] == 1
    assert ok.json()["prompt"] == "a person walks:3; a person bows:2"
    assert bvh.status_code == 200 and bvh.text.startswith("HIERARCHY")
    assert bad_total.status_code == 422 and "at most 120 s" in bad_total.json()["error"]
    assert bad_empty.status_code == 422 and "segments" in bad_empty.json()["error"]
    assert bad_prompt.status_code == 422 and "segments.0.prompt" in bad_prompt.json()["error"]


def test_a_request_over_the_work_budget_is_refused_before_it_runs(pipe):
    """A request's work (seconds x steps, guidance and cleanup) is known before it runs: past the budget, 422."""
    from stablemofusion.core import limits
    from stablemofusion.serve.server_limits import MAX_REQUEST_COST

    heavy = {"segments": [{"prompt": "a person walks", "seconds": 7.5}] * 16, "steps": 50, "footskate": "loop"}
    light = {**heavy, "steps": 1, "footskate": "post"}
    assert limits.request_cost(120, 50, True, "loop") > MAX_REQUEST_COST >= limits.request_cost(120, 1, False, "post")
    over, ok = call(create_app(pipe), ("POST", "/v1/timeline", heavy), ("POST", "/v1/timeline", light))
    assert over.status_code == 422 and "units of work" in over.json()["error"]
    assert ok.status_code == 200 and ok.json()["frames"] == 2400
