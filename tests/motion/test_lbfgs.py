"""The numpy pose optimisation: its hand-derived gradient matches finite differences, and the L-BFGS finds minima."""

import numpy as np

from stablemofusion.motion.files import load_motion
from stablemofusion.motion.lbfgs import lbfgs
from stablemofusion.motion.rigid import CM, _PoseParams, _squared_distance, fit_rigid
from stablemofusion.motion.skeleton import get_skeleton


def test_a_pose_loss_gradient_through_the_pose_parametrisation_is_the_finite_difference():
    motion = fit_rigid(load_motion("example:wave-both-hands").joints[:30].astype(np.float64))
    body = _PoseParams(motion, get_skeleton("humanml3d"))
    x0 = motion.joints()
    target = x0 * CM + np.random.default_rng(1).normal(size=x0.shape)  # the rigid fit's loss (used by method="lbfgs")
    f = body.objective(_squared_distance(target))
    assert np.abs(body.positions(body.theta0)[0] / CM - x0).max() < 1e-9  # the start poses the motion itself
    rng = np.random.default_rng(0)
    theta = body.theta0 + rng.normal(size=body.theta0.shape) * 0.5
    _, grad = f(theta)
    for i in rng.choice(len(theta), 40, replace=False):
        e = np.zeros_like(theta)
        e[i] = 1e-6
        numeric = (f(theta + e)[0] - f(theta - e)[0]) / 2e-6
        assert abs(numeric - grad[i]) <= 1e-3 * (abs(numeric) + abs(grad[i])) + 1e-7


def test_lbfgs_minimises_a_quadratic_and_rosenbrock():
    a = np.diag(np.arange(1.0, 11.0))
    b = np.arange(10.0)
    x = lbfgs(lambda v: (0.5 * v @ a @ v - b @ v, a @ v - b), np.zeros(10), 50, max_evals=200)
    np.testing.assert_allclose(x, np.linalg.solve(a, b), atol=1e-6)

    def rosen(v):
        x, y = v
        return (1 - x) ** 2 + 100 * (y - x * x) ** 2, np.array([-2 * (1 - x) - 400 * x * (y - x * x), 200 * (y - x * x)])

    start = np.array([-1.2, 1.0])
    end = lbfgs(rosen, start, 200, max_evals=1000)
    assert rosen(end)[0] < 1e-8 < rosen(start)[0]
