"""Write the robots the package ships (stablemofusion/assets/robots/{g1,h1}) from the Unitree descriptions in
../shared/data/robots (MuJoCo Menagerie's, with BODY_25 keypoint sites; BSD-3-Clause): the MJCF unchanged, its
meshes decimated so that both robots fit in the wheel, the licences beside them. Build-time tools, not package
dependencies: ``pip install trimesh fast-simplification``.

    python packaging/slim_robots.py [--source ../shared/data/robots] [--ratio 0.1]

At the end it checks the copies against the originals in MuJoCo: the same joints, masses and inertias, the same
site positions in 200 random poses.
"""

from __future__ import annotations

import argparse
import re
import shutil
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOTS = {"g1": ("unitree_g1", "g1.xml"), "h1": ("unitree_h1", "h1.xml")}


def decimate(src: Path, dst: Path, ratio: float) -> tuple[int, int]:
    import fast_simplification
    import trimesh

    mesh = trimesh.load(src, force="mesh", process=True)  # an STL is a triangle soup: its vertices merged first
    faces = len(mesh.faces)
    if faces > 200:
        v, f = fast_simplification.simplify(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces),
                                            target_reduction=1 - ratio)
        mesh = trimesh.Trimesh(v, f, process=True)  # merged vertices, then faces wound one way (outward normals)
        trimesh.repair.fix_normals(mesh)
    dst.write_bytes(mesh.export(file_type="stl"))
    return faces, len(mesh.faces)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--source", type=Path, default=ROOT.parent / "shared" / "data" / "robots")
    ap.add_argument("--out", type=Path, default=ROOT / "stablemofusion" / "assets" / "robots")
    ap.add_argument("--ratio", type=float, default=0.1, help="share of each mesh's triangles kept")
    args = ap.parse_args()
    for name, (folder, xml) in ROBOTS.items():
        src, dst = args.source / folder, args.out / name
        if dst.exists():
            shutil.rmtree(dst)
        (dst / "assets").mkdir(parents=True)
        text = (src / xml).read_text()
        shutil.copy(src / xml, dst / xml)
        shutil.copy(src / "scene.xml", dst / "scene.xml")
        shutil.copy(src / "LICENSE", dst / "LICENSE.txt")
        shutil.copy(args.source / "LICENSE-menagerie", dst / "LICENSE-menagerie.txt")
        before = after = 0
        for mesh in sorted(set(re.findall(r'file="([^"]+)"', text))):
            b, a = decimate(src / "assets" / mesh, dst / "assets" / mesh, args.ratio)
            before, after = before + b, after + a
        (dst / "README.md").write_text(
            f"# Unitree {name.upper()} (MJCF for MuJoCo)\n\n"
            f"From MuJoCo Menagerie's `{folder}` description (as kept in a public fork that marks human keypoints as "
            f"`BODY_25:*` sites). `{xml}` and `scene.xml` are unchanged; the meshes in `assets/` were decimated by "
            f"`packaging/slim_robots.py` to {args.ratio:.0%} of their triangles ({before:,} -> {after:,}) so the "
            f"package can ship them.\n\nLicence: BSD-3-Clause, Unitree Robotics (`LICENSE.txt`); Menagerie's notes "
            f"in `LICENSE-menagerie.txt`.\n")
        size = sum(p.stat().st_size for p in dst.rglob("*") if p.is_file())
        print(f"{name}: {before:,} -> {after:,} triangles, {size / 1e6:.2f} MB")
    check(args)


def check(args) -> None:
    import mujoco

    rng = np.random.default_rng(0)
    for name, (folder, _) in ROBOTS.items():
        a = mujoco.MjModel.from_xml_path(str(args.source / folder / "scene.xml"))
        b = mujoco.MjModel.from_xml_path(str(args.out / name / "scene.xml"))
        assert (a.nq, a.nv, a.nu, a.nbody, a.njnt) == (b.nq, b.nv, b.nu, b.nbody, b.njnt)
        mass = np.abs(a.body_mass - b.body_mass).max()
        inertia = np.abs(a.body_inertia - b.body_inertia).max()
        da, db = mujoco.MjData(a), mujoco.MjData(b)
        worst, contacts = 0.0, [0, 0]
        for _ in range(200):
            q = a.qpos0.copy()
            lo, hi = a.jnt_range[1:, 0], a.jnt_range[1:, 1]
            q[7:] = rng.uniform(lo, hi)
            for k, (m, d) in enumerate(((a, da), (b, db))):
                d.qpos[:] = q
                mujoco.mj_kinematics(m, d)
                mujoco.mj_collision(m, d)
                n = d.ncon
                bodies = m.geom_bodyid[d.contact.geom[:n]] if n else np.zeros((0, 2), int)
                contacts[k] += int(((bodies > 0).all(axis=1) & (d.contact.dist[:n] < 0)).sum()) if n else 0
            worst = max(worst, float(np.abs(da.site_xpos - db.site_xpos).max()))
        print(f"{name}: mass diff {mass:.2e} kg, inertia diff {inertia:.2e}, site diff {worst:.2e} m over 200 poses;"
              f" self-contacts in them: original {contacts[0]}, slim {contacts[1]}")


if __name__ == "__main__":
    main()
