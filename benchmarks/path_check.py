"""Paths from words, measured on the held-out path prompts (benchmarks/paths/heldout.jsonl, written before the path
words were built): the body's heading change (the hips' facing, last frames against the first) against the words',
circles' closure, distance travelled by gait, skating with footskate post (against the same prompts without their
path words, and with --data against the corpus's real walks and runs, weighted like the prompts' gaits),
bone-length rigidity, the label classifier's content for the walks and runs (a walk with a turn, sideways or backwards
is still a walk); and the time of a path prompt against
the same prompt without its path words on each runtime.

And explicit paths (``path=``, `smf generate --path`): for walks and runs along a few waypoint shapes, the root's
closest approach to every waypoint (goal 0.3 m) and skating with post.

    python benchmarks/path_check.py [--classifier CL --data CORPUS] [--seed 0] [--torch]
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np
from runtime_speed import _timed

HERE = Path(__file__).resolve().parent
TOLERANCE_DEG = 30.0


def facing_change(joints: np.ndarray) -> float:
    """Degrees (positive: to the left) the hips' facing turned from the first 5 frames to the last 5."""
    across = joints[:, 1] - joints[:, 2]
    face = np.cross(across, np.array([0.0, 1.0, 0.0]))
    yaw = np.unwrap(np.arctan2(face[:, 0], face[:, 2]))
    return float(np.degrees(yaw[-5:].mean() - yaw[:5].mean()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--prompts", type=Path, default=HERE / "paths" / "heldout.jsonl")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--classifier", type=Path, default=None)
    ap.add_argument("--data", type=Path, default=None, help="the labelled corpus of the classifier's labels")
    ap.add_argument("--torch", action="store_true", help="time the torch path too")
    args = ap.parse_args()
    from stablemofusion.footskate.metrics import mean_metrics
    from stablemofusion.motion.rigid import bone_length_deviation
    from stablemofusion.core.path_plan import parse_path
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    warnings.simplefilter("ignore")
    items = [json.loads(line) for line in args.prompts.read_text().splitlines() if line.strip()]
    pipe = MotionPipeline.from_pretrained(backend="onnx", threads=1)
    rows, joints, plain = [], [], []
    for k, it in enumerate(items):
        spec = parse_path(it["prompt"])
        r = pipe(it["prompt"], seed=args.seed + k)[0]
        if spec is not None:  # the same prompt without its path words, same length and seed
            plain.append(pipe(spec.prompt, seconds=len(r.joints) / r.fps, seed=args.seed + k)[0].joints)
        xz = r.joints[:, 0, [0, 2]]
        got = facing_change(r.joints)
        rows.append({"prompt": it["prompt"], "kind": it["kind"], "want": it["turn"], "got": round(got, 1),
                     "read": None if spec is None else [spec.kind, spec.angle, spec.prompt],
                     "ok": abs(got - it["turn"]) <= TOLERANCE_DEG, "seconds": len(r.joints) / r.fps,
                     "closure_m": round(float(np.linalg.norm(xz[-1] - xz[0])), 2),
                     "distance_m": round(float(np.linalg.norm(np.diff(xz, axis=0), axis=-1).sum()), 2),
                     "gait": it["gait"], "bone_worst_mm": round(bone_length_deviation(r.joints)["bone_worst"] * 1000, 3)})
        joints.append(r.joints)
    circles = [r for r in rows if r["kind"] == "circle"]
    walk = [r["distance_m"] for r in rows if r["gait"] == "walk" and r["kind"] in ("circle", "half", "curve", "zigzag", "back")]
    run = [r["distance_m"] for r in rows if r["gait"] == "run" and r["kind"] in ("circle", "half", "curve", "zigzag", "back")]
    out = {"prompts": len(rows), "within_30_deg": sum(r["ok"] for r in rows),
           "share_within_30_deg": round(sum(r["ok"] for r in rows) / len(rows), 3),
           "by_kind": {k: f"{sum(r['ok'] for r in rows if r['kind'] == k)}/{sum(r['kind'] == k for r in rows)}"
                       for k in sorted({r["kind"] for r in rows})},
           "read_as_a_path": sum(r["read"] is not None for r in rows),
           "circles_closing_within_1m": f"{sum(r['closure_m'] <= 1.0 for r in circles)}/{len(circles)}",
           "circle_closure_m_median": float(np.median([r["closure_m"] for r in circles])),
           "distance_walk_m_median": float(np.median(walk)), "distance_run_m_median": float(np.median(run)),
           "skate_post": round(mean_metrics(joints)["skate_ratio"], 4),
           "skate_post_without_path_words": round(mean_metrics(plain)["skate_ratio"], 4),
           "bone_worst_mm_max": max(r["bone_worst_mm"] for r in rows),
           "misses": [{k: r[k] for k in ("prompt", "want", "got", "read")} for r in rows if not r["ok"]]}
    # time: a path prompt against the same prompt without its path words (what the model is given), 4 s, same seed
    pairs = [(r["prompt"], r["read"][2]) for r in rows if r["read"] is not None][:8]
    runtimes = {"onnx": (pipe, {})}
    if args.torch:
        from stablemofusion.pipelines.motion_pipeline import MotionPipeline

        runtimes["torch-fast"] = (MotionPipeline.from_pretrained(), {"engine": "fast"})
    out["time_ms"] = {}
    for name, (p, kw) in runtimes.items():
        with_path = _timed(lambda: [p(a, seconds=4, seed=1, **kw) for a, _ in pairs], 5) / len(pairs)
        without = _timed(lambda: [p(b, seconds=4, seed=1, **kw) for _, b in pairs], 5) / len(pairs)
        out["time_ms"][name] = {"path_prompt": round(with_path * 1000, 2), "without_path_words": round(without * 1000, 2),
                                "ratio": round(with_path / without, 3)}
    if args.data is not None:  # real motion of the prompts' gaits: dataset-2 walks and runs of the corpus
        from stablemofusion.eval.classifier import corpus_labels

        labels = corpus_labels(args.data)
        real = {}
        for gait in ("walk", "run"):
            ids = sorted(k for k, v in labels.items() if v.dataset == 2 and v.content == gait and not k.startswith("M"))
            real[gait] = mean_metrics([np.load(args.data / "new_joints" / f"{k}.npy") for k in ids])["skate_ratio"]
        out["skate_real_by_gait"] = {g: round(v, 4) for g, v in real.items()}
        out["skate_real_weighted"] = round(float(np.mean([real[r["gait"]] for r in rows])), 4)
    if args.classifier is not None:
        from stablemofusion.eval.classifier import corpus_labels, load_classifier
        from stablemofusion.eval.prompts import PromptItem, prompt_accuracy

        moving = [PromptItem(prompt=it["prompt"], contents=(it["gait"],), styles=(), dataset=2, ood=False)
                  for it in items if it["kind"] in ("circle", "half", "curve", "zigzag", "back")]
        acc = prompt_accuracy(pipe, load_classifier(args.classifier), moving, corpus_labels(args.data), samples=1,
                              seconds=None, seed=args.seed)
        family = lambda c: "run" if c in ("run", "dash") else "walk" if c.startswith("walk") else c  # noqa: E731
        kept = [family(r["got"][0][0]) == r["want"][0][0] for r in acc["per_prompt"]]
        out["classifier_content_walks_and_runs"] = acc["all"]
        out["classifier_walks_stay_walks_runs_stay_runs"] = f"{sum(kept)}/{len(kept)}"
    out["explicit_paths"] = explicit_paths(pipe, args.seed)
    print(json.dumps(out, indent=1, default=float))


SHAPES = {"square": [[0, 0], [0, 3], [3, 3], [3, 0]], "L": [[0, 0], [0, 4], [-3, 4]],
          "zigzag": [[0, 0], [1.5, 2], [0, 4], [1.5, 6], [0, 8]], "S": [[0, 0], [1, 1.5], [0, 3], [-1, 4.5], [0, 6]],
          "long loop": [[0, 0], [0, 6], [6, 6], [6, 0], [0, 0]]}


def explicit_paths(pipe, seed: int) -> dict:
    """The root's closest approach to each waypoint of walks and runs along SHAPES, and their skating (post)."""
    from stablemofusion.footskate.metrics import mean_metrics

    out, worst, joints = {}, 0.0, []
    for name, points in SHAPES.items():
        for prompt in ("a person walks", "a person runs", "an old man walks slowly", "a happy woman jogs"):
            r = pipe(prompt, path=points, seed=seed)[0]
            xz = r.joints[:, 0, [0, 2]]
            gap = max(float(np.linalg.norm(xz - np.asarray(p, float), axis=-1).min()) for p in points)
            worst = max(worst, gap)
            joints.append(r.joints)
            out[f"{name} / {prompt}"] = {"seconds": len(r.joints) / r.fps, "farthest_waypoint_m": round(gap, 3)}
    return {"runs": out, "farthest_waypoint_m": round(worst, 3), "skate_post": round(mean_metrics(joints)["skate_ratio"], 4)}


if __name__ == "__main__":
    main()
