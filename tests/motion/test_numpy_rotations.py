"""The numpy conversions that replace scipy's on the portable runtime: Euler angles (every Tait-Bryan order,
gimbal lock included), quaternions from matrices and Gaussian smoothing give scipy's results."""

import numpy as np
import pytest

from stablemofusion.core.errors import SMFError
from stablemofusion.motion.features import gaussian_smooth
from stablemofusion.motion.rotation import matrix_to_euler, matrix_to_quat

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation
ORDERS = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]


@pytest.mark.parametrize("order", ORDERS)
def test_euler_angles_are_scipys_and_give_back_the_rotation_at_gimbal_lock_too(order):
    rng = np.random.default_rng(0)
    m = Rotation.random(2000, random_state=1).as_matrix()
    np.testing.assert_allclose(matrix_to_euler(m, order), Rotation.from_matrix(m).as_euler(order, degrees=True),
                               atol=1e-9)
    locked = np.c_[rng.uniform(-180, 180, 40), np.where(rng.random(40) < 0.5, -90.0, 90.0), rng.uniform(-180, 180, 40)]
    g = Rotation.from_euler(order, locked, degrees=True).as_matrix()
    back = Rotation.from_euler(order, matrix_to_euler(g, order), degrees=True).as_matrix()
    assert np.abs(back - g).max() < 1e-12


def test_euler_orders_must_name_three_distinct_axes():
    with pytest.raises(SMFError, match="Euler order"):
        matrix_to_euler(np.eye(3), "ZXZ")


def test_quaternions_are_scipys_with_w_positive():
    m = np.concatenate([Rotation.random(2000, random_state=2).as_matrix(), np.diag([1.0, -1, -1])[None],
                        np.diag([-1.0, 1, -1])[None], np.diag([-1.0, -1, 1])[None]])
    xyzw = Rotation.from_matrix(m).as_quat()
    want = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], -1) * np.where(xyzw[:, 3:] < 0, -1.0, 1.0)
    got = matrix_to_quat(m)
    assert np.abs(np.abs((got * want).sum(-1)) - 1).max() < 1e-12 and (got[:, 0] >= 0).all()


@pytest.mark.parametrize("sigma", [0.5, 1.0, 2.5, 9.0])
def test_gaussian_smoothing_is_scipys_nearest_mode(sigma):
    gaussian_filter1d = pytest.importorskip("scipy.ndimage").gaussian_filter1d
    x = np.random.default_rng(3).normal(size=(40, 3))
    np.testing.assert_allclose(gaussian_smooth(x, sigma), gaussian_filter1d(x, sigma, axis=0, mode="nearest"),
                               atol=1e-12)
    np.testing.assert_allclose(gaussian_smooth(x[:3], sigma), gaussian_filter1d(x[:3], sigma, axis=0, mode="nearest"),
                               atol=1e-12)
