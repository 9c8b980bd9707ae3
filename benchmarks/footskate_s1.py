"""Footskate on UnderPressure's S1_Hopping capture (100 fps, measured insole forces and contacts).

Prints, as JSON: the vGRF error of our UnderPressure port against the measured forces (per-foot totals),
and the contact F1 of each route against the measured contacts: the rule on the measured forces (upper
bound of the force route), our port's forces, the kinematic detector on the capture's own 23 joints, and,
on the capture converted to our 22 joints at 20 fps, the kinematic detector and the distilled 22-joint model.

    python benchmarks/footskate_s1.py --underpressure ../shared/data/underpressure/pretrained.tar \
        --s1 ../shared/data/underpressure/S1_Hopping.pth [--vgrf-model FILE]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from stablemofusion.footskate.contacts import (UP_FOOT_JOINTS, contact_f1, contacts_from_underpressure_labels,
                                               contacts_from_vgrf, kinematic_contacts)
from stablemofusion.footskate.underpressure import (load_s1, load_underpressure, retarget_23_to_22,
                                                    vgrf_from_joints22, vgrf_from_joints23)
from stablemofusion.motion.resample import resample


def _f1s(pred: np.ndarray, true: np.ndarray) -> dict:
    names = ("left_heel", "left_toe", "right_heel", "right_toe")
    return {"all": round(contact_f1(pred, true), 4),
            **{n: round(contact_f1(pred[:, i], true[:, i]), 4) for i, n in enumerate(names)}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--underpressure", type=Path, required=True)
    ap.add_argument("--s1", type=Path, required=True)
    ap.add_argument("--vgrf-model", type=Path, default=None, help="distilled 22-joint model (default: shipped)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    net = load_underpressure(args.underpressure)
    d = load_s1(args.s1)
    true = contacts_from_underpressure_labels(d["contacts"])
    t = time.perf_counter()
    forces = vgrf_from_joints23(net, d["joints"])
    seconds = time.perf_counter() - t
    pred, meas = forces.sum(-1), d["forces"].sum(-1)
    report = {
        "frames": len(true),
        "port_vgrf": {
            "foot_rmse_bw": round(float(np.sqrt(((pred - meas) ** 2).mean())), 4),
            "foot_corr": round(float(np.corrcoef(pred.ravel(), meas.ravel())[0, 1]), 4),
            "left_corr": round(float(np.corrcoef(pred[:, 0], meas[:, 0])[0, 1]), 4),
            "right_corr": round(float(np.corrcoef(pred[:, 1], meas[:, 1])[0, 1]), 4),
            "cell_rmse_bw": round(float(np.sqrt(((forces - d["forces"]) ** 2).mean())), 4),
            "seconds": round(seconds, 3),
        },
        "contact_f1": {
            "rule_on_measured_forces": _f1s(contacts_from_vgrf(d["forces"], 100.0), true),
            "vgrf_port": _f1s(contacts_from_vgrf(forces, 100.0), true),
            "kinematic_23_joints_100fps": _f1s(kinematic_contacts(d["joints"], 100.0, foot_joints=UP_FOOT_JOINTS,
                                                                  up_axis=2), true),
        },
    }
    j22 = retarget_23_to_22(d["joints"])  # 20 fps
    true20 = resample(true.astype(float), 100.0, 20.0) > 0.5
    report["contact_f1"]["kinematic_22_joints_20fps"] = _f1s(kinematic_contacts(j22, 20.0), true20)
    meas20 = resample(d["forces"].astype(float), 100.0, 20.0)
    m20 = meas20.sum(-1)
    # the port through our 22-joint path: 22 -> 23 retarget, 20 -> 100 -> 20 fps
    via22 = vgrf_from_joints22(net, j22, 20.0)
    report["port_via_22_joints_20fps"] = {
        "foot_rmse_bw": round(float(np.sqrt(((via22.sum(-1) - m20) ** 2).mean())), 4),
        "foot_corr": round(float(np.corrcoef(via22.sum(-1).ravel(), m20.ravel())[0, 1]), 4),
    }
    report["contact_f1"]["vgrf_port_via_22_joints_20fps"] = _f1s(contacts_from_vgrf(via22, 20.0), true20)
    from stablemofusion.footskate.vgrf import load_vgrf_model, shipped_vgrf_model_path

    path = args.vgrf_model or shipped_vgrf_model_path()
    if path is not None:
        student = load_vgrf_model(path)
        with torch.no_grad():
            f22 = student(torch.as_tensor(j22, dtype=torch.float32)[None])[0].double().numpy()
        p20 = f22.sum(-1)
        report["student_vgrf_20fps"] = {
            "model": str(path),
            "foot_rmse_bw": round(float(np.sqrt(((p20 - m20) ** 2).mean())), 4),
            "foot_corr": round(float(np.corrcoef(p20.ravel(), m20.ravel())[0, 1]), 4),
        }
        report["contact_f1"]["vgrf_student_22_joints_20fps"] = _f1s(contacts_from_vgrf(f22, 20.0), true20)
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
