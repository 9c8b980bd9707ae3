"""A humanoid robot described by MJCF, as the retargeting reads it: its joints and their ranges, the sites the
human joints drive, its feet's soles, its size. Needs MuJoCo (``pip install 'stablemofusion[robot]'``)."""

from __future__ import annotations

import copy
import json
import threading
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from ..core.errors import SMFError
from ..motion.skeleton import HUMANML3D
from .kinematics import Chain, chain_of
from .mj import mujoco

BUILT_IN = ("g1", "h1")  # shipped in assets/robots/<name>/scene.xml (decimated meshes, BSD-3-Clause, Unitree)
FOOT_JOINTS = ("left_ankle", "right_ankle")
NEAR = 0.02  # m: two of the robot's own bodies this close are near each other (``Robot.near`` reports them)
FOOT_CLEARANCE = 0.02  # m kept between the two soles' inner edges by the ankles' targets (``Robot.min_gap``)


def require_mujoco() -> None:
    if mujoco is None:
        raise SMFError("retargeting to a robot needs MuJoCo: pip install 'stablemofusion[robot]' (or: pip install "
                       "mujoco)")


def robot_file(robot: str | Path) -> Path:
    """The MJCF file of a built-in robot name (g1, h1: its scene, floor included) or a path."""
    if str(robot).lower() in BUILT_IN:
        return Path(str(resources.files("stablemofusion") / "assets" / "robots" / str(robot).lower() / "scene.xml"))
    path = Path(robot)
    if path.suffix.lower() != ".xml":
        raise SMFError(f"robot must be one of {', '.join(BUILT_IN)} or an MJCF .xml file, got {str(robot)!r}")
    if not path.is_file():
        raise SMFError(f"robot file {path} does not exist")
    return path


def read_joint_map(path: str | Path | None, robot: str | None = None) -> tuple[dict[str, str], dict[str, float]]:
    """(human joint -> robot site, human joint -> weight) from a joint-map JSON (``{"sites": {...}, "weights":
    {...}}``; weights default to 1); None: the shipped map onto the BODY_25 sites (with a shipped ``robot``'s own
    corrections)."""
    if path is None:
        text = (resources.files("stablemofusion") / "assets" / "robots_keypoints.json").read_text(encoding="utf-8")
        where = "the shipped joint map"
    else:
        where = str(path)
        try:
            text = Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise SMFError(f"cannot read the joint map {where}: {e.strerror if isinstance(e, OSError) else e}")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise SMFError(f"the joint map {where} is not JSON: {e.msg} (line {e.lineno})") from None
    sites = data.get("sites") if isinstance(data, dict) else None
    if path is None and robot in data.get("robots", {}):
        sites = {**sites, **data["robots"][robot]["sites"]}
    if not isinstance(sites, dict) or not sites or not all(isinstance(v, str) for v in sites.values()):
        raise SMFError(f"the joint map {where} needs \"sites\": {{human joint: robot site name}}")
    unknown = sorted(set(sites) - set(HUMANML3D.joint_names))
    if unknown:
        raise SMFError(f"the joint map {where} names joints the motion does not have: {', '.join(unknown)} "
                       f"(known: {', '.join(HUMANML3D.joint_names)})")
    missing = [j for j in FOOT_JOINTS + ("pelvis",) if j not in sites]
    if missing:
        raise SMFError(f"the joint map {where} must map {', '.join(missing)} (the feet and the pelvis place the robot)")
    weights = data.get("weights", {})
    if not isinstance(weights, dict) or not all(isinstance(w, (int, float)) and 0 <= w <= 100
                                                for w in weights.values()):
        raise SMFError(f"the joint map {where}: \"weights\" must be numbers from 0 to 100")
    return dict(sites), {j: float(weights.get(j, 1.0)) for j in sites}


@dataclass(frozen=True)
class Sole:
    """A foot's lowest collision points in its body's frame: ``points`` (P, 3) m, ``radius`` (P,) m (a sphere's or
    capsule's; 0 for a box's or mesh's corners); ``toe`` and ``heel`` (3,) at sole level, front and back."""

    body: int
    points: np.ndarray
    radius: np.ndarray
    toe: np.ndarray
    heel: np.ndarray


class Robot:
    """An MJCF humanoid with a free joint at its root, read once: ``model`` (MuJoCo), ``joint_names`` and
    ``ranges`` (J, 2) rad of its hinge joints in qpos order, the sites ``sites`` (K,) driven by the human joints
    ``human`` (K,) with ``weights`` (K,), the two feet's ``soles``, ``leg`` (hip to knee to ankle at rest, m) and
    ``rest_ankle`` (ankle site above the sole, flat footed, m), ``min_gap`` (how far apart sideways its ankles stay
    so that the soles keep ``FOOT_CLEARANCE`` between them, m); ``chain`` its tree for kinematics of many poses at
    once; ``own`` the model for its self-contacts (the world's geoms collide with nothing), ``near`` the same reporting
    them up to ``NEAR`` apart (slower), ``rest_near`` the pairs of geoms that near at the reference pose."""

    def __init__(self, path: str | Path, joint_map: str | Path | None = None, name: str | None = None):
        require_mujoco()
        self.path = robot_file(path)
        stem = self.path.parent.name if self.path.stem == "scene" else self.path.stem
        self.name = name or (str(path).lower() if str(path).lower() in BUILT_IN else stem)
        try:
            self.model = mujoco.MjModel.from_xml_path(str(self.path))
        except ValueError as e:
            raise SMFError(f"MuJoCo cannot load {self.path}: {str(e).splitlines()[0]}") from None
        m = self.model
        if m.njnt == 0 or int(m.jnt_type[0]) != int(mujoco.mjtJoint.mjJNT_FREE):
            raise SMFError(f"{self.path}: the robot's first joint must be a free joint (its floating base)")
        hinge = [j for j in range(1, m.njnt) if int(m.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE),
                                                                        int(mujoco.mjtJoint.mjJNT_SLIDE))]
        if len(hinge) != m.njnt - 1 or m.nq != 7 + len(hinge):
            raise SMFError(f"{self.path}: only one free joint and hinge or slide joints are supported")
        if np.bincount(m.jnt_bodyid, minlength=m.nbody).max() > 1:
            raise SMFError(f"{self.path}: a body with more than one joint is not supported (one hinge or slide each)")
        self.joint_names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}" for j in hinge)
        lo = np.where(m.jnt_limited[hinge].astype(bool), m.jnt_range[hinge, 0], -np.inf)
        hi = np.where(m.jnt_limited[hinge].astype(bool), m.jnt_range[hinge, 1], np.inf)
        self.ranges = np.stack([lo, hi], axis=1)
        sites, weights = read_joint_map(joint_map, self.name)
        ids = {}
        for joint, site in sites.items():
            sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, site)
            if sid < 0:
                raise SMFError(f"{self.path} has no site named {site!r} (the joint map maps {joint} to it)")
            ids[joint] = sid
        self.human = np.array([HUMANML3D.joint_names.index(j) for j in ids])
        self.human_names = tuple(ids)
        self.sites = np.array(list(ids.values()))
        self.weights = np.array([weights[j] for j in ids])
        self.free_body = int(m.jnt_bodyid[0])
        self.chain: Chain = chain_of(m, self.free_body)
        self.own = copy.deepcopy(m)  # the robot alone: the world's geoms (its floor) collide with nothing
        fixed = self.own.geom_bodyid == 0
        self.own.geom_contype[fixed], self.own.geom_conaffinity[fixed] = 0, 0
        self.near = copy.deepcopy(self.own)  # and its contacts reported NEAR apart, not only where bodies overlap
        self.near.geom_margin[:] = NEAR
        self._scratch = threading.local()
        data = mujoco.MjData(m)
        self.rest = self.neutral()
        self.rest_near = self._near_pairs(self.rest)
        data.qpos[:] = self.rest
        mujoco.mj_kinematics(m, data)
        at = {j: data.site_xpos[ids[j]].copy() for j in ids}
        self.soles = tuple(self._sole(data, ids[j]) for j in FOOT_JOINTS)
        low = min(self.sole_heights(data, s).min() for s in self.soles)
        if all(j in at for j in ("left_hip", "left_knee", "left_ankle")):
            self.leg = float(np.linalg.norm(at["left_hip"] - at["left_knee"])
                             + np.linalg.norm(at["left_knee"] - at["left_ankle"]))
        else:
            self.leg = float(at["pelvis"][2] - at["left_ankle"][2])
        for joint, where in at.items():  # a left joint's site on the robot's left (+y) at rest, a right one's right
            side = {"left": 1.0, "right": -1.0}.get(joint.split("_")[0])
            if side is not None and where[1] * side < 0:
                raise SMFError(f"{self.path}: site {sites[joint]!r}, which the joint map gives {joint}, lies on the "
                               f"robot's {'right' if side > 0 else 'left'} side at rest; map {joint} to a site on "
                               f"its {joint.split('_')[0]} side (--robot-map)")
        self.rest_ankle = float(at["left_ankle"][2] - low)
        # how far apart sideways the ankles must stay for the soles not to meet: each sole's inner edge from its ankle
        inner_left = at["left_ankle"][1] - self._sole_edges(data, self.soles[0])[0]
        inner_right = self._sole_edges(data, self.soles[1])[1] - at["right_ankle"][1]
        self.min_gap = float(inner_left + inner_right) + FOOT_CLEARANCE
        self.rest_toe = data.xmat[self.soles[0].body].reshape(3, 3) @ self.soles[0].toe \
            + data.xpos[self.soles[0].body] - at["left_ankle"]

    def scratch(self) -> tuple:
        """This thread's ``MjData`` of ``own`` and of ``near``, made once per thread (making one costs about as much
        as a pose's kinematics and collisions 30 times over): working space that no call keeps between calls."""
        data = getattr(self._scratch, "data", None)
        if data is None:
            data = self._scratch.data = (mujoco.MjData(self.own), mujoco.MjData(self.near))
        return data

    def _near_pairs(self, qpos: np.ndarray) -> np.ndarray:
        """(ngeom, ngeom) bool: the pairs of the robot's own geoms nearer than ``NEAR`` in the pose ``qpos`` (at the
        reference pose, those its build puts close together)."""
        m = self.near
        data = mujoco.MjData(m)
        data.qpos[:] = qpos
        mujoco.mj_kinematics(m, data)
        mujoco.mj_collision(m, data)
        geoms = data.contact.geom[:data.ncon]
        geoms = geoms[(m.geom_bodyid[geoms] > 0).all(axis=1)]
        out = np.zeros((m.ngeom, m.ngeom), dtype=bool)
        out[geoms[:, 0], geoms[:, 1]] = out[geoms[:, 1], geoms[:, 0]] = True
        return out

    def neutral(self) -> np.ndarray:
        """(nq,) the model's reference pose (qpos0) with every joint moved inside its range."""
        q = self.model.qpos0.copy()
        q[7:] = np.clip(q[7:], self.ranges[:, 0], self.ranges[:, 1])
        return q

    def _sole(self, data, site: int) -> Sole:
        """The sole of the foot whose ankle is ``site``: the lowest body at rest among the site's body and its
        descendants that has collision geoms."""
        m = self.model
        start = int(m.site_bodyid[site])
        family = [b for b in range(m.nbody) if self._descends(b, start)]
        best = None
        for b in family:
            pts, rad = self._collision_points(b)
            if not len(pts):
                continue
            world = (data.xmat[b].reshape(3, 3) @ pts.T).T + data.xpos[b]
            low = float((world[:, 2] - rad).min())
            if best is None or low < best[0]:
                best = (low, b, pts, rad, world)
        if best is None:
            raise SMFError(f"{self.path}: the foot below site {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_SITE, site)!r}"
                           " has no collision geoms to stand on")
        low, b, pts, rad, world = best
        bottom = np.abs(world[:, 2] - rad - low) < 0.02  # the points the foot stands on
        forward = world[:, 0]
        rot = data.xmat[b].reshape(3, 3)
        sole_world = lambda i: rot.T @ (np.array([world[i, 0], world[bottom, 1].mean(), low]) - data.xpos[b])
        toe = sole_world(int(np.argmax(np.where(bottom, forward, -np.inf))))
        heel = sole_world(int(np.argmin(np.where(bottom, forward, np.inf))))
        return Sole(b, pts, rad, toe, heel)

    def _descends(self, body: int, ancestor: int) -> bool:
        while body > 0:
            if body == ancestor:
                return True
            body = int(self.model.body_parentid[body])
        return ancestor == 0

    def _collision_points(self, body: int) -> tuple[np.ndarray, np.ndarray]:
        """(P, 3) points in the body's frame that bound its collision geoms from below, (P,) their radii."""
        m, pts, rad = self.model, [], []
        for g in np.nonzero(m.geom_bodyid == body)[0]:
            if m.geom_contype[g] == 0 and m.geom_conaffinity[g] == 0:
                continue
            rot = np.empty(9)
            mujoco.mju_quat2Mat(rot, m.geom_quat[g])
            rot, pos, size = rot.reshape(3, 3), m.geom_pos[g], m.geom_size[g]
            kind = int(m.geom_type[g])
            if kind == int(mujoco.mjtGeom.mjGEOM_SPHERE):
                local, r = np.zeros((1, 3)), size[0]
            elif kind == int(mujoco.mjtGeom.mjGEOM_CAPSULE):
                local, r = np.array([[0, 0, -size[1]], [0, 0, size[1]]]), size[0]
            elif kind == int(mujoco.mjtGeom.mjGEOM_BOX):
                local, r = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * size, 0.0
            elif kind == int(mujoco.mjtGeom.mjGEOM_MESH):
                mid = m.geom_dataid[g]
                a, n = m.mesh_vertadr[mid], m.mesh_vertnum[mid]
                local, r = np.asarray(m.mesh_vert[a:a + n], dtype=float), 0.0
            else:
                continue
            pts.append(local @ rot.T + pos)
            rad.append(np.full(len(local), r))
        if not pts:
            return np.zeros((0, 3)), np.zeros(0)
        return np.concatenate(pts), np.concatenate(rad)

    @staticmethod
    def _sole_edges(data, sole: Sole) -> tuple[float, float]:
        """A sole's right and left edges (lowest and highest y, m) in ``data``'s pose."""
        y = (data.xmat[sole.body].reshape(3, 3) @ sole.points.T).T[:, 1] + data.xpos[sole.body][1]
        return float((y - sole.radius).min()), float((y + sole.radius).max())

    def sole_heights(self, data, sole: Sole) -> np.ndarray:
        """(P,) m: the sole points' lowest heights above the floor (z = 0) in ``data``'s pose."""
        world = (data.xmat[sole.body].reshape(3, 3) @ sole.points.T).T + data.xpos[sole.body]
        return world[:, 2] - sole.radius


@lru_cache(maxsize=8)
def load_robot(robot: str, joint_map: str | None = None) -> Robot:
    """A robot read once per process (built-in name or MJCF path, and joint map path)."""
    return Robot(robot, joint_map)
