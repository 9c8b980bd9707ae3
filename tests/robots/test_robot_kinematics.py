"""The robot's kinematics for many poses at once against MuJoCo's own, pose by pose: the points, every Jacobian
column (mj_jacSite), and the integration of velocity coordinates (mj_integratePos)."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="the robot extra (pip install 'stablemofusion[robot]')")

from stablemofusion.robots import kinematics as kin  # noqa: E402
from stablemofusion.robots.model import load_robot  # noqa: E402


def random_poses(robot, n: int, seed: int = 0) -> np.ndarray:
    """(n, nq) poses: the base anywhere, turned anyhow, every joint anywhere in its range."""
    rng = np.random.default_rng(seed)
    q = np.repeat(robot.rest[None], n, axis=0)
    q[:, :3] += rng.normal(size=(n, 3))
    turn = rng.normal(size=(n, 4))
    q[:, 3:7] = turn / np.linalg.norm(turn, axis=1, keepdims=True)
    q[:, 7:] = rng.uniform(robot.ranges[:, 0], robot.ranges[:, 1], size=(n, len(robot.joint_names)))
    return q


@pytest.mark.parametrize("name", ["g1", "h1"])
def test_points_and_jacobians_match_mujoco_pose_by_pose(name):
    robot = load_robot(name)
    m, d = robot.model, mujoco.MjData(robot.model)
    q = random_poses(robot, 12)
    poses = kin.forward(m, mujoco.MjData(m), robot.chain, q)
    bodies = m.site_bodyid[robot.sites]
    at = kin.points(poses, bodies, m.site_pos[robot.sites])
    jac = kin.jacobians(robot.chain, poses, at, bodies)
    single = kin.jacobians(robot.chain, poses, at, bodies, np.float32)
    for t in range(len(q)):
        d.qpos[:] = q[t]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        assert np.abs(d.site_xpos[robot.sites] - at[t]).max() < 1e-12
        for k, site in enumerate(robot.sites):
            want = np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, want, None, site)
            assert np.abs(want - jac[t, k]).max() < 1e-12 and np.abs(want - single[t, k]).max() < 1e-5


def test_per_pose_bodies_give_each_pose_its_own_points_jacobian():
    robot = load_robot("g1")
    m = robot.model
    q = random_poses(robot, 3, seed=1)
    poses = kin.forward(m, mujoco.MjData(m), robot.chain, q)
    bodies = np.array([[5, 0], [0, 9], [12, 12]])  # body 0, the world: a point that does not move
    at = np.random.default_rng(2).normal(size=(3, 2, 3))
    jac = kin.jacobians(robot.chain, poses, at, bodies)
    for t in range(3):
        for p in range(2):
            alone = kin.jacobians(robot.chain, kin.Poses(*(x[t:t + 1] for x in (poses.rot, poses.pos, poses.axis,
                                                                                  poses.origin, poses.moment))),
                                  at[t:t + 1, p:p + 1], bodies[t, p:p + 1])
            assert np.allclose(jac[t, p], alone[0, 0], rtol=0, atol=1e-12)
    assert not jac[0, 1].any() and not jac[1, 0].any()


def test_height_jacobians_are_the_jacobians_height_rows():
    robot = load_robot("g1")
    m = robot.model
    q = random_poses(robot, 4, seed=5)
    poses = kin.forward(m, mujoco.MjData(m), robot.chain, q)
    bodies = np.array([0, 3, 7, 12, 20])
    at = np.random.default_rng(6).normal(size=(4, 5, 3))
    want = kin.jacobians(robot.chain, poses, at, bodies)[:, :, 2]
    assert np.allclose(kin.height_jacobians(robot.chain, poses, at, bodies), want, rtol=0, atol=1e-12)
    assert not kin.height_jacobians(robot.chain, poses, at, bodies)[:, 0].any()


def test_integration_matches_mujoco():
    robot = load_robot("h1")
    m = robot.model
    q = random_poses(robot, 10, seed=3)
    dq = np.random.default_rng(4).normal(0, 0.3, size=(10, m.nv))
    got = kin.integrate(q, dq)
    for t in range(10):
        want = q[t].copy()
        mujoco.mj_integratePos(m, want, dq[t], 1.0)
        assert np.abs(want - got[t]).max() < 1e-12


def test_solve_spd_solves_each_system_and_leaves_the_matrices():
    """Symmetric positive definite systems the size of the G1's (35 velocity coordinates), solved one by one by
    MuJoCo's Cholesky: the same answers as numpy's LU, the matrices untouched (the solve adds rows to some and solves
    them again)."""
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(7, 60, 35))
    a = np.swapaxes(rows, 1, 2) @ rows + 0.01 * np.eye(35)
    b = rng.normal(size=(7, 35))
    kept = a.copy()
    x = kin.solve_spd(a, b)
    np.testing.assert_allclose(x, np.linalg.solve(a, b[..., None])[..., 0], rtol=1e-8, atol=1e-10)
    np.testing.assert_array_equal(a, kept)
    assert kin.solve_spd(a[:0], b[:0]).shape == (0, 35)
