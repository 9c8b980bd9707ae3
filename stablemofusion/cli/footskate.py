"""`smf footskate distil|contacts|clean`: distil a 22-joint vGRF model, print contacts, clean a motion file."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Foot contacts, footskate cleanup and the distillation of a 22-joint vGRF "
                                   "model from UnderPressure (non-commercial weights, supplied by you).")
    fs = p.add_subparsers(dest="footskate_command", metavar="ACTION", required=True)

    d = fs.add_parser("distil", help="distil a 22-joint vGRF model from UnderPressure on a corpus")
    d.add_argument("--underpressure", type=Path, required=True, help="UnderPressure pretrained.tar (never shipped)")
    d.add_argument("--data", type=Path, required=True, help="HumanML3D-layout folder (new_joints/, train.txt)")
    d.add_argument("--out", type=Path, required=True, help="output .safetensors (a .json is written beside)")
    d.add_argument("--steps", type=int, default=3000)
    d.add_argument("--limit", type=int, default=None, help="use only the first N training motions")
    d.add_argument("--seed", type=int, default=0)
    d.set_defaults(func=run_distil)

    c = fs.add_parser("contacts", help="print foot contacts and skate metrics of a motion file")
    c.add_argument("motion", help="joints/features .npy, .bvh or example:NAME")
    c.add_argument("--route", choices=("kinematic", "vgrf"), default="kinematic")
    c.add_argument("--vgrf-model", type=Path, default=None, help="distilled model (default: shipped one)")
    c.add_argument("--underpressure", type=Path, default=None, help="use UnderPressure itself for --route vgrf")
    c.set_defaults(func=run_contacts)

    k = fs.add_parser("clean", help="remove foot skating from a motion file, write features and joints .npy")
    k.add_argument("motion", help="joints/features .npy, .bvh or example:NAME")
    k.add_argument("--out", type=Path, required=True, help="output stem: writes STEM_features.npy, STEM_joints.npy")
    k.add_argument("--route", choices=("kinematic", "vgrf"), default="kinematic")
    k.add_argument("--vgrf-model", type=Path, default=None, help="distilled model for the vGRF loss/contacts")
    k.set_defaults(func=run_clean)


def vgrf_model_from_args(path: Path | None, underpressure: Path | None = None, required: bool = False):
    """The vGRF callable to use: UnderPressure (retargeted), a distilled file, the shipped one, or None."""
    from ..core.errors import SMFError
    from ..footskate.vgrf import load_vgrf_model, shipped_vgrf_model_path

    if underpressure is not None:
        from ..footskate.underpressure import TeacherOn22, load_underpressure

        return TeacherOn22(load_underpressure(underpressure))
    path = path or shipped_vgrf_model_path()
    if path is None:
        if required:
            raise SMFError("no vGRF model: pass --vgrf-model FILE (see 'smf footskate distil')")
        return None
    return load_vgrf_model(path)


def run_distil(args: argparse.Namespace) -> None:
    import torch

    from ..core.errors import SMFError
    from ..footskate.vgrf import distil, load_corpus_joints, save_vgrf_model
    from ..footskate.underpressure import load_underpressure

    if args.steps < 1:
        raise SMFError(f"--steps must be positive, got {args.steps}")
    teacher = load_underpressure(args.underpressure)
    torch.set_num_threads(max(1, min(4, torch.get_num_threads())))
    train = load_corpus_joints(args.data, "train", args.limit)
    val = load_corpus_joints(args.data, "test", None if args.limit is None else max(1, args.limit // 5))
    model, figures = distil(teacher, train, val, steps=args.steps, seed=args.seed)
    save_vgrf_model(model, args.out, {"figures": figures, "data": str(args.data)})
    print(json.dumps(figures))
    print(f"wrote {args.out.with_suffix('.safetensors')} (+ .json); licence: non-commercial (UnderPressure)")


def _load(motion: str):
    from ..footskate.metrics import footskate_metrics  # noqa: F401  (import check)
    from ..motion.files import load_motion

    m = load_motion(motion)
    if m.skeleton.name != "humanml3d":
        from ..core.errors import SMFError

        raise SMFError("footskate tools need a HumanML3D (22-joint) motion")
    return m


def run_contacts(args: argparse.Namespace) -> None:
    from ..footskate.cleanup import CleanupConfig, detect_contacts
    from ..footskate.metrics import footskate_metrics

    m = _load(args.motion)
    model = vgrf_model_from_args(args.vgrf_model, args.underpressure, required=args.route == "vgrf")
    c = detect_contacts(m.joints, m.fps, CleanupConfig(contacts=args.route), model)
    names = ("left_ankle", "left_toe", "right_ankle", "right_toe")
    print(json.dumps({"frames": len(c), "contact_fraction": {n: round(float(c[:, i].mean()), 3) for i, n in enumerate(names)},
                      **{k: round(v, 4) for k, v in footskate_metrics(m.joints, m.fps).items()}}))


def run_clean(args: argparse.Namespace) -> None:
    from ..footskate.cleanup import CleanupConfig, cleanup_features, cleanup_joints, features_from_cleaned
    from ..footskate.metrics import footskate_metrics, joint_change
    from ..core.io import save_npy

    m = _load(args.motion)
    model = vgrf_model_from_args(args.vgrf_model, required=args.route == "vgrf")
    config = CleanupConfig(contacts=args.route)
    if m.features is None:  # a joints file keeps its own skeleton (median bone lengths)
        joints = cleanup_joints(m.joints, m.fps, config, vgrf_model=model).joints
        feats = features_from_cleaned(joints)
    else:  # a features file gets the pipeline's final stage: rigid fit, cleanup, written in its own frames
        feats, motion = cleanup_features(m.features, config, vgrf_model=model, fps=m.fps)
        joints = motion.joints()
    save_npy(args.out.with_name(args.out.name + "_features.npy"), feats.astype("float32"))
    save_npy(args.out.with_name(args.out.name + "_joints.npy"), joints.astype("float32"))
    before, after = footskate_metrics(m.joints, m.fps), footskate_metrics(joints, m.fps)
    print(json.dumps({"before": before, "after": after, "joint_change_m": joint_change(m.joints, joints)}))
