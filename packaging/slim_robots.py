"""Write the robots the package ships (stablemofusion/assets/robots/{g1,h1}) from the Unitree descriptions in
../shared/data/robots (MuJoCo Menagerie's, with BODY_25 keypoint sites; BSD-3-Clause, Unitree Robotics), small
enough for the wheel: the MJCF files (g1.xml / h1.xml and scene.xml) copied byte for byte, only the meshes g1.xml /
h1.xml reference (no hand variants, no MJX files, no images), each mesh decimated, the licences beside them
(LICENSE.txt: the robot's LICENSE; LICENSE-menagerie.txt: Menagerie's licence note for its directory) and a README.

Decimation: quadric edge collapse (fast-simplification) of each mesh, its STL triangle soup merged into shared
vertices first, run to a quadric-error threshold rather than to a triangle count, over a ladder of thresholds. Each
candidate is measured (the largest distance from its vertices to the original surface and from the original's
vertices to it, in mm), must open no hole (no more open edges than the original), keep its faces wound one way, and
load in MuJoCo; every mesh then ships its fewest-triangle candidate within one shared deviation bound, the smallest
bound with which both folders together fit in ``--budget-mb`` (default 4.0 MB). Meshes are written as binary STL
under their original names, so the MJCF needs no edit. Every body of both robots has an explicit ``<inertial>``: no
mass or inertia comes from a mesh (checked).

Build-time tools, not dependencies of stablemofusion (nothing at run time imports them):

    pip install fast-simplification trimesh rtree mujoco   # rtree: trimesh's closest-point queries

    python packaging/slim_robots.py [--source ../shared/data/robots] [--out stablemofusion/assets/robots]
    python packaging/slim_robots.py --check-only      # only the check, of the copies already written

It takes about 6 minutes on one core. At the end it checks the copies against the originals in MuJoCo and prints
the figures: both load (robot and scene); the same sizes (nq, nv, nu, nbody, njnt, ...); the same model arrays
(bodies, joints and their ranges, actuators, sites, geom classes, keyframes); body masses and inertias equal (1e-9);
all site positions (every ``BODY_25:*`` site) identical in 200 seeded random poses inside the joint ranges; each
mesh's deviation and bounding-box shift in mm; self-contacts (mj_collision contacts between two of the robot's own
bodies) in the default pose, the keyframes and the random poses, original against copy.
"""

from __future__ import annotations

import argparse
import os
import shutil
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOTS = {"g1": ("unitree_g1", "g1.xml"), "h1": ("unitree_h1", "h1.xml")}
# quadric-error thresholds tried, coarsest first (m^2; fast-simplification's is absolute: the mesh is scaled to set it)
LADDER = [10.0 ** e for e in np.arange(-3.0, -7.01, -0.25)]
FINE_MM = 1.0  # a mesh's ladder stops at the first candidate within this deviation (the original is one too)
SEED, POSES = 0, 200
NOTES = {  # what a reader of a copy should know about the source itself (kept as it is)
    "h1": "Kept as in the source: `BODY_25:RWrist` is marked on `left_elbow_link` and `BODY_25:LWrist` on\n"
          "`right_elbow_link` (the wrist sites sit on the arms opposite to their names).\n",
}


# ----------------------------------------------------------------------------------------------------------- meshes
def load_stl(path: Path):
    import trimesh

    return trimesh.load(path, force="mesh", process=True)  # an STL is a triangle soup: its vertices merged first


def stl_bytes(mesh) -> bytes:
    import trimesh

    return trimesh.exchange.stl.export_stl(mesh)  # binary STL


def border_edges(mesh) -> int:
    import trimesh

    return len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1))


def deviation_mm(orig, slim) -> tuple[float, float]:
    """(largest distance of slim's vertices from orig's surface, of orig's vertices from slim's surface), mm."""
    import trimesh

    _, a, _ = trimesh.proximity.closest_point(orig, slim.vertices)
    _, b, _ = trimesh.proximity.closest_point(slim, orig.vertices)
    return float(a.max()) * 1e3, float(b.max()) * 1e3


def loads_in_mujoco(data: bytes, density: float) -> bool:
    """Whether MuJoCo compiles the mesh as these robots use it (a mesh geom, a mass from its volume where dense)."""
    import mujoco

    xml = (f'<mujoco><asset><mesh name="m" file="m.stl"/></asset><worldbody><body><freejoint/>'
           f'<geom type="mesh" mesh="m" density="{density}"/><geom type="sphere" size="0.01"/></body></worldbody>'
           f'</mujoco>')
    try:
        mujoco.MjModel.from_xml_string(xml, {"m.stl": data})
        return True
    except ValueError:
        return False


def candidates(path: Path, density: float) -> tuple[object, list[dict]]:
    """The original mesh and its decimations along the ladder, each {faces, dev (mm, both ways), bytes}."""
    import fast_simplification
    import trimesh

    orig = load_stl(path)
    out = [{"faces": len(orig.faces), "dev": (0.0, 0.0), "bytes": path.read_bytes()}]
    wound, borders = orig.is_winding_consistent, border_edges(orig)
    seen = {len(orig.faces)}
    for threshold in LADDER:
        # fast-simplification's threshold at its last pass is 1e-9 * 102**agg, in the mesh's units squared
        scale = np.sqrt(1e-9 * 102.0 ** 7 / threshold)
        v, f = fast_simplification.simplify(orig.vertices * scale, orig.faces, target_count=4, agg=7)
        # float32 as the STL stores them; a collapse can leave a pinched (non-manifold) edge, never a hole: an
        # open edge more than the original's rejects the candidate (so do faces wound against their neighbours')
        mesh = trimesh.Trimesh((v / scale).astype(np.float32).astype(np.float64), f, process=True)
        mesh.remove_unreferenced_vertices()
        if len(mesh.faces) in seen or len(mesh.faces) < 4:
            continue
        seen.add(len(mesh.faces))
        if border_edges(mesh) > borders or (wound and not mesh.is_winding_consistent):
            continue
        data = stl_bytes(mesh)
        if not loads_in_mujoco(data, density):
            continue
        dev = deviation_mm(orig, mesh)
        out.append({"faces": len(mesh.faces), "dev": dev, "bytes": data})
        if max(dev) <= FINE_MM:
            break
    return orig, out


def choose(per_mesh: dict, budget_bytes: int) -> tuple[float, dict]:
    """The smallest deviation bound whose fewest-triangle candidates fit the budget, and those candidates."""
    bounds = sorted({max(c["dev"]) for cands in per_mesh.values() for c in cands})
    for bound in bounds:
        pick = {k: min((c for c in cands if max(c["dev"]) <= bound), key=lambda c: c["faces"])
                for k, cands in per_mesh.items()}
        if sum(len(c["bytes"]) for c in pick.values()) <= budget_bytes:
            return bound, pick
    raise SystemExit(f"the meshes do not fit in {budget_bytes / 1e6:.2f} MB even at the ladder's end")


# ------------------------------------------------------------------------------------------------------------- build
def mesh_files(xml_path: Path) -> dict[str, str]:
    """mesh name -> file, as the MJCF names them."""
    import mujoco

    spec = mujoco.MjSpec.from_file(str(xml_path))
    return {m.name: m.file for m in spec.meshes}


def menagerie_note(source: Path, folder: str) -> str:
    """The section of Menagerie's licence notes (LICENSE-menagerie) for this robot's directory, verbatim."""
    text = (source / "LICENSE-menagerie").read_text(encoding="utf-8")
    bar = "=" * 80
    head = f"{bar}\nLicense for contents in the directory '{folder}/'\n{bar}\n"
    start = text.index(head)
    end = text.find(f"\n\n{bar}\nLicense for contents in the directory", start + len(head))
    return text[start:end if end >= 0 else len(text)].rstrip("\n") + "\n"


def readme(name: str, folder: str, xml: str, rows: list[dict], bound: float) -> str:
    before, after = sum(r["orig_faces"] for r in rows), sum(r["faces"] for r in rows)
    lines = [
        f"# Unitree {name.upper()}: MJCF for MuJoCo, with decimated meshes",
        "",
        f"From MuJoCo Menagerie's `{folder}` description",
        f"(https://github.com/google-deepmind/mujoco_menagerie/tree/main/{folder}), as kept in a public fork that",
        "marks body keypoints as MuJoCo sites named `BODY_25:*` (OpenPose BODY_25 names).",
        "",
        f"- `{xml}` and `scene.xml` (the robot, a floor and a light): copied unchanged, byte for byte; every body,",
        "  joint, joint range, actuator, inertial, site and geom class is the source's.",
        f"- `assets/`: the {len(rows)} meshes `{xml}` references (the source's other variants and their meshes are "
        "left",
        "  out), decimated by `packaging/slim_robots.py` (fast-simplification quadric edge collapse, bounded by the",
        f"  deviation): {before:,} -> {after:,} triangles, a triangle ratio of {after / before:.3f} overall (per mesh "
        "below);",
        f"  no vertex of a copy lies more than {bound:.1f} mm from the original surface, nor any original vertex that",
        "  far from the copy. Binary STL under the original file names.",
        "- No body's mass or inertia comes from a mesh: every body has an explicit `<inertial>`.",
        "",
        "Licence: BSD-3-Clause, Copyright (c) 2016-2023 HangZhou YuShu TECHNOLOGY CO.,LTD. (\"Unitree Robotics\"):",
        f"`LICENSE.txt` (the source's `{folder}/LICENSE`). `LICENSE-menagerie.txt`: MuJoCo Menagerie's licence note",
        f"for its `{folder}/` directory (that section of the Menagerie's notes, verbatim).",
        "",
    ]
    if name in NOTES:
        lines += [NOTES[name]]
    lines += ["| mesh | triangles | ratio | deviation (mm) |", "|---|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['file']} | {r['orig_faces']:,} -> {r['faces']:,} | {r['faces'] / r['orig_faces']:.3f} "
                     f"| {max(r['dev']):.2f} |")
    return "\n".join(lines) + "\n"


def build(args) -> None:
    import mujoco

    t0 = time.time()
    files, per_mesh, orig_faces = {}, {}, {}
    for name, (folder, xml) in ROBOTS.items():
        src = args.source / folder
        files[name] = mesh_files(src / xml)
        spec = mujoco.MjSpec.from_file(str(src / xml))
        for mesh_name, file in files[name].items():
            density = max([float(g.density) for g in spec.geoms if g.meshname == mesh_name] + [0.0])
            orig, per_mesh[(name, file)] = candidates(src / "assets" / file, density)
            orig_faces[(name, file)] = len(orig.faces)
            print(f"  {name} {file}: {len(orig.faces):,} triangles, {len(per_mesh[(name, file)]) - 1} candidates "
                  f"({time.time() - t0:.0f} s)", flush=True)
    # everything but the meshes: the MJCF, the licences, a README (its size allowed for before it is written)
    other = {}
    for name, (folder, xml) in ROBOTS.items():
        src = args.source / folder
        other[name] = {xml: (src / xml).read_bytes(), "scene.xml": (src / "scene.xml").read_bytes(),
                       "LICENSE.txt": (src / "LICENSE").read_bytes(),
                       "LICENSE-menagerie.txt": menagerie_note(args.source, folder).encode()}
    fixed = sum(len(b) for fs in other.values() for b in fs.values()) + 6000 * len(ROBOTS)
    bound, pick = choose(per_mesh, int(args.budget_mb * 1e6) - fixed)
    print(f"deviation bound {bound:.2f} mm: the smallest with which both folders fit in {args.budget_mb} MB")

    args.out.mkdir(parents=True, exist_ok=True)
    for name, (folder, xml) in ROBOTS.items():
        tmp = args.out / f".{name}.tmp"
        if tmp.exists():
            shutil.rmtree(tmp)
        (tmp / "assets").mkdir(parents=True)
        for fname, data in other[name].items():
            (tmp / fname).write_bytes(data)
        rows = []
        for file in files[name].values():
            c = pick[(name, file)]
            (tmp / "assets" / file).write_bytes(c["bytes"])
            rows.append({"file": file, "orig_faces": orig_faces[(name, file)], "faces": c["faces"], "dev": c["dev"]})
        (tmp / "README.md").write_text(readme(name, folder, xml, rows, bound), encoding="utf-8")
        dst = args.out / name
        if dst.exists():
            shutil.rmtree(dst)
        os.replace(tmp, dst)  # the old copy is gone only for the moment of the swap
    print(f"written in {time.time() - t0:.0f} s")


# ------------------------------------------------------------------------------------------------------------- check
def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def self_contacts(m, d) -> tuple[int, frozenset, frozenset, float]:
    """Contacts between two of the robot's own bodies (the floor, body 0, left out): their number, their geom pairs,
    their body pairs, and the deepest penetration (m, 0 without contact)."""
    n = d.ncon
    if not n:
        return 0, frozenset(), frozenset(), 0.0
    geoms = d.contact.geom[:n]
    bodies = m.geom_bodyid[geoms]
    mine = (bodies > 0).all(axis=1) & (bodies[:, 0] != bodies[:, 1])
    depth = float(max(0.0, -d.contact.dist[:n][mine].min())) if mine.any() else 0.0
    return (int(mine.sum()), frozenset(tuple(sorted(map(int, g))) for g in geoms[mine]),
            frozenset(tuple(sorted(map(int, b))) for b in bodies[mine]), depth)


def random_poses(m, rng, n: int) -> np.ndarray:
    import mujoco

    q = np.tile(m.qpos0, (n, 1))
    for j in range(m.njnt):
        a, kind = m.jnt_qposadr[j], int(m.jnt_type[j])
        if kind == int(mujoco.mjtJoint.mjJNT_FREE):
            q[:, a:a + 3] = rng.uniform([-1, -1, 0.5], [1, 1, 1.5], (n, 3))
            quat = rng.normal(size=(n, 4))
            q[:, a + 3:a + 7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        elif kind in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            lo, hi = m.jnt_range[j] if m.jnt_limited[j] else (-np.pi, np.pi)
            q[:, a] = rng.uniform(lo, hi, n)
        else:
            raise SystemExit(f"joint {j}: a ball joint, not drawn")
    return q


SAME_ARRAYS = [  # model arrays that the meshes must not touch: compared exactly
    "body_parentid", "body_pos", "body_quat", "body_jntnum", "body_geomnum", "jnt_type", "jnt_bodyid", "jnt_pos",
    "jnt_axis", "jnt_range", "jnt_limited", "jnt_actfrcrange", "dof_armature", "dof_damping", "dof_frictionloss",
    "actuator_trntype", "actuator_trnid", "actuator_gainprm", "actuator_biasprm", "actuator_ctrlrange",
    "actuator_forcerange", "site_bodyid", "site_pos", "site_quat", "site_size", "site_type", "geom_type",
    "geom_bodyid", "geom_contype", "geom_conaffinity", "geom_group", "geom_priority", "geom_condim", "geom_friction",
    "geom_matid", "geom_dataid", "key_qpos", "key_ctrl", "qpos0",
]


def check(args) -> None:
    import mujoco

    rng = np.random.default_rng(SEED)
    total = 0
    for name, (folder, xml) in ROBOTS.items():
        src, dst = args.source / folder, args.out / name
        size = folder_bytes(dst)
        total += size
        files = mesh_files(src / xml)
        print(f"\n== {name} ({dst.relative_to(ROOT) if dst.is_relative_to(ROOT) else dst}): {size / 1e6:.3f} MB "
              f"(the source's meshes that {xml} references: "
              f"{sum((src / 'assets' / f).stat().st_size for f in set(files.values())) / 1e6:.2f} MB)")
        for a_path, b_path in ((src / xml, dst / xml), (src / "scene.xml", dst / "scene.xml")):
            same_text = a_path.read_bytes() == b_path.read_bytes()
            a = mujoco.MjModel.from_xml_path(str(a_path))
            b = mujoco.MjModel.from_xml_path(str(b_path))
            sizes = ("nq", "nv", "nu", "nbody", "njnt", "ngeom", "nsite", "nmesh", "nkey")
            va, vb = [getattr(a, s) for s in sizes], [getattr(b, s) for s in sizes]
            assert va == vb, (a_path.name, va, vb)
            print(f"{b_path.name}: loads; text identical to the source: {same_text}; "
                  + " ".join(f"{s} {v}" for s, v in zip(sizes, vb)) + " (equal)")
        # the robot in its scene from here on: the keyframes are there (H1's is in scene.xml); the floor is body 0
        spec = mujoco.MjSpec.from_file(str(dst / xml))
        implicit = [bd.name for bd in spec.bodies[1:] if not bd.explicitinertial]
        print(f"bodies without an explicit <inertial> (mass/inertia from their geoms): {implicit or 'none'}")
        diff = [k for k in SAME_ARRAYS if not np.array_equal(getattr(a, k), getattr(b, k))]
        assert not diff, diff
        print(f"{len(SAME_ARRAYS)} model arrays (bodies, joints and ranges, actuators, sites, geom classes, "
              "keyframes) identical")
        worst = {k: float(np.abs(getattr(a, k) - getattr(b, k)).max())
                 for k in ("body_mass", "body_inertia", "body_ipos", "body_iquat")}
        assert max(worst.values()) <= 1e-9, worst
        print(f"total mass {a.body_mass.sum():.4f} kg; largest differences: "
              + ", ".join(f"{k} {v:.1e}" for k, v in worst.items()))
        da, db = mujoco.MjData(a), mujoco.MjData(b)
        body25 = [i for i in range(a.nsite) if a.site(i).name.startswith("BODY_25:")]

        def contacts(q):
            out = []
            for m, d in ((a, da), (b, db)):
                d.qpos[:] = q
                mujoco.mj_kinematics(m, d)
                mujoco.mj_collision(m, d)
                out.append(self_contacts(m, d))
            return out

        poses = [("default pose (qpos0)", a.qpos0)] + [(f"keyframe '{a.key(k).name}'", a.key_qpos[k])
                                                        for k in range(a.nkey)]
        for label, q in poses:
            (na, *_), (nb, *_) = contacts(q)
            print(f"self-contacts in the {label}: original {na}, slim {nb}")
        qs = random_poses(a, rng, POSES)
        site_dev, identical = 0.0, True
        n = np.zeros((2, 4), int)  # contacts, colliding geom pairs, colliding body pairs, poses with any
        same_pairs = same_n = 0
        depth = []
        for q in qs:
            ra, rb = contacts(q)
            identical = identical and np.array_equal(da.site_xpos, db.site_xpos)
            site_dev = max(site_dev, float(np.abs(da.site_xpos - db.site_xpos).max()))
            for k, r in enumerate((ra, rb)):
                n[k] += (r[0], len(r[1]), len(r[2]), r[0] > 0)
            same_pairs += ra[2] == rb[2]
            same_n += ra[0] == rb[0]
            if ra[0] and rb[0]:
                depth.append(abs(ra[3] - rb[3]))
        print(f"{POSES} random poses (seed {SEED}, joints uniform in their ranges, the base anywhere): "
              f"{len(body25)} BODY_25 sites (of {a.nsite} sites) "
              + ("bit-identical in every pose" if identical else f"differ by up to {site_dev:.3e} m"))
        assert identical
        print(f"  self-contacts (mj_collision; MuJoCo's multi-contact gives up to 4 per pair of convex meshes): "
              f"original {n[0, 0]}, slim {n[1, 0]} ({(n[1, 0] - n[0, 0]) / max(n[0, 0], 1):+.1%}); the same count in "
              f"{same_n}/{POSES} poses")
        change = (n[1, 1] - n[0, 1]) / max(n[0, 1], 1)
        print(f"  colliding geom pairs: original {n[0, 1]}, slim {n[1, 1]} ({change:+.1%}); body pairs: {n[0, 2]} / "
              f"{n[1, 2]}; poses with any: {n[0, 3]} / {n[1, 3]}; the same colliding body pairs in "
              f"{same_pairs}/{POSES} poses")
        if depth:
            print(f"  deepest penetration, where both collide ({len(depth)} poses): differs by "
                  f"{np.mean(depth) * 1e3:.2f} mm on average, {np.max(depth) * 1e3:.2f} mm at most")

        # each mesh: its deviation, both ways, and its bounding box's shift
        print("  mesh (C: collides)                   triangles         ratio slim->orig  orig->slim  bbox  (mm)")
        worst_c = worst_v = 0.0
        tri = [0, 0]
        for mesh_name, file in files.items():
            mid = mujoco.mj_name2id(a, mujoco.mjtObj.mjOBJ_MESH, mesh_name)
            gs = np.flatnonzero((a.geom_dataid == mid) & (a.geom_type == int(mujoco.mjtGeom.mjGEOM_MESH)))
            collides = bool(any(a.geom_contype[g] or a.geom_conaffinity[g] for g in gs))
            orig, slim = load_stl(src / "assets" / file), load_stl(dst / "assets" / file)
            dev = deviation_mm(orig, slim)
            box = float(np.abs(orig.bounds - slim.bounds).max()) * 1e3  # the bounding box's largest shift
            tri = [tri[0] + len(orig.faces), tri[1] + len(slim.faces)]
            if collides:
                worst_c = max(worst_c, *dev)
            else:
                worst_v = max(worst_v, *dev)
            print(f"  {'C' if collides else ' '} {file:34s} {len(orig.faces):6,} -> {len(slim.faces):6,}  "
                  f"{len(slim.faces) / len(orig.faces):5.3f}  {dev[0]:10.2f}  {dev[1]:10.2f}  {box:5.2f}")
        print(f"  {name}: {tri[0]:,} -> {tri[1]:,} triangles, ratio {tri[1] / tri[0]:.3f}; largest deviation: "
              f"collision meshes {worst_c:.2f} mm (the convex hulls MuJoCo collides move no more), visual-only "
              f"meshes {worst_v:.2f} mm")
    print(f"\nboth folders: {total / 1e6:.3f} MB (budget {args.budget_mb} MB)")
    assert total <= args.budget_mb * 1e6, total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", type=Path, default=ROOT.parent / "shared" / "data" / "robots",
                    help="the folder with unitree_g1/, unitree_h1/ and LICENSE-menagerie (default: ../shared/data/"
                         "robots from the repository root)")
    ap.add_argument("--out", type=Path, default=ROOT / "stablemofusion" / "assets" / "robots",
                    help="where g1/ and h1/ are written (default: stablemofusion/assets/robots)")
    ap.add_argument("--budget-mb", type=float, default=4.0, help="both folders together, in MB (1e6 bytes)")
    ap.add_argument("--check-only", action="store_true", help="only check the copies already written")
    args = ap.parse_args()
    args.source, args.out = args.source.resolve(), args.out.resolve()
    if not args.check_only:
        build(args)
    check(args)


if __name__ == "__main__":
    main()
