"""docs/images/character_strip.png: one generated motion on our skeleton, on a raw Bandai-Namco BVH rig and on
the Mixamo-style test rig (`smf generate --rig ... --joint-map ...`), drawn bone by bone with matplotlib.

    python benchmarks/character_strip.py BANDAI.bvh [OUT.png]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from stablemofusion.cli.main import main  # noqa: E402
from stablemofusion.motion.bvh import forward_kinematics, read_bvh  # noqa: E402
from stablemofusion.motion.skeleton import HUMANML3D  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FRAMES = (0, 15, 30, 45, 60, 75)
PROMPT = "a person walks forward"


def draw(ax, pos: np.ndarray, parents, colour: str, title: str, centre: np.ndarray, skip: int = -1) -> None:
    """Bones of pos (J, 3) metres Y up as lines, seen from the character's right-front; bones from joint
    ``skip`` are left out (Bandai-Namco's joint_Root stays at the origin while its Hips carry the path)."""
    for j, p in enumerate(parents):
        if p >= 0 and p != skip:
            seg = pos[[p, j]] - centre
            ax.plot(seg[:, 0], seg[:, 2], seg[:, 1], color=colour, lw=2)
    shown = [j for j in range(len(pos)) if j != skip]
    ax.scatter(*(pos[shown] - centre)[:, [0, 2, 1]].T, s=6, color="k")
    ax.set_xlim(-0.8, 0.8), ax.set_ylim(-0.8, 0.8), ax.set_zlim(0, 1.9)
    xx, zz = np.meshgrid(np.linspace(-0.8, 0.8, 5), np.linspace(-0.8, 0.8, 5))
    ax.plot_wireframe(xx, zz, np.zeros_like(xx), color="0.8", lw=0.5)
    ax.view_init(elev=12, azim=-50)
    ax.set_box_aspect((1.6, 1.6, 1.9))
    ax.set_axis_off()
    ax.set_title(title, fontsize=8)


def main_(bandai: Path, out: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        args = ["generate", PROMPT, "--seconds", "4", "--seed", "0", "--device", "cpu", "--format", "npy"]
        assert main([*args, "--out", str(tmp / "b"), "--rig", str(bandai), "--joint-map", "bandai-namco"]) == 0
        assert main([*args, "--out", str(tmp / "m"), "--rig", str(REPO / "tests/data/mixamo_tpose.bvh"),
                     "--joint-map", "mixamo"]) == 0
        stem = "000_a_person_walks_forward"
        ours = np.load(tmp / "b" / f"{stem}_joints.npy")
        rigs = [read_bvh(tmp / d / f"{stem}_rig.bvh") for d in ("b", "m")]
    rows = [("ours (HumanML3D, 22 joints)", ours, HUMANML3D.parents, "tab:blue"),
            (f"Bandai-Namco rig ({rigs[0].num_joints} joints)", forward_kinematics(rigs[0]), rigs[0].parents, "tab:orange"),
            (f"Mixamo-style rig ({rigs[1].num_joints} joints)", forward_kinematics(rigs[1]), rigs[1].parents, "tab:green")]
    fig = plt.figure(figsize=(2.2 * len(FRAMES), 2.6 * len(rows)), dpi=90)
    for r, (title, pos, parents, colour) in enumerate(rows):
        for c, f in enumerate(FRAMES):
            ax = fig.add_subplot(len(rows), len(FRAMES), r * len(FRAMES) + c + 1, projection="3d")
            centre = np.array([ours[f, 0, 0], 0.0, ours[f, 0, 2]])  # the same camera target for every row
            draw(ax, pos[f], parents, colour, f"{title}\nframe {f}" if c == 0 else f"frame {f}", centre,
                 skip=0 if r == 1 else -1)
    fig.suptitle(f'"{PROMPT}" (seed 0, 4 s) on three skeletons', fontsize=10)
    fig.tight_layout()
    fig.savefig(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main_(Path(sys.argv[1]), Path(sys.argv[2]) if len(sys.argv) > 2 else REPO / "docs/images/character_strip.png")
