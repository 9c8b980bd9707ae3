"""Leaning into turns: the body tilts towards the centre of the curve its root follows, as real people do.

Measured on the corpus's walks, runs and turning walks (``benchmarks/final_stage_check.py lean``): the torso's
sideways lean (pelvis to neck, from vertical, both smoothed over :data:`SMOOTH_S`) follows
``LEAN_SHARE * atan(a_lat / g)``, where ``a_lat`` is the sideways acceleration of the root's smoothed ground path
(``v * omega`` on a curve). :func:`lean_into_turns` adds, where a motion leans less than that, the missing part:
the body above the legs turns about the pelvis (the legs are placed afterwards by the footskate cleanup).
"""

from __future__ import annotations

import numpy as np

from . import timeseries as ts
from .arrays import device, namespace
from .ik import LEG_CHAIN_JOINTS

G = 9.81  # m/s^2
LEAN_SHARE = 0.65  # measured slope of lean against atan(a_lat / g) on the corpus (least squares through 0)
SMOOTH_S = 0.5  # s: the Gaussian (standard deviation) over which the path and the lean are smoothed
MAX_LEAN_DEG = 30.0
MOVING = (0.3, 0.6)  # m/s: below the first speed nobody leans into a "turn" (a sway of a standing body), above the
# second the full lean (the corpus fit is of frames faster than 0.5 m/s); smoothstep between
NECK = 12


def _batched(fn):
    """Let a function of joints (B, T, 22, 3) take one motion (T, 22, 3) too (its results without the batch)."""

    def one_or_many(joints, *args, **kwargs):
        if joints.ndim == 3:
            out = fn(joints[None], *args, **kwargs)
            return tuple(o[0] for o in out) if isinstance(out, tuple) else out[0]
        return fn(joints, *args, **kwargs)

    one_or_many.__doc__, one_or_many.__name__ = fn.__doc__, fn.__name__
    return one_or_many


def smooth(x, sigma: float):
    """``x`` (B, T, ...) smoothed along time by a Gaussian of ``sigma`` frames reaching 3 sigmas (edges held)."""
    return ts.window(x, ts.gaussian(sigma, 3.0), edge=True)


@_batched
def turn_frame(joints, fps: float):
    """Of joints (B, T, 22, 3) metres: the unit direction of travel (B, T, 2) (x, z), the sideways acceleration of
    the smoothed root path (B, T) m/s^2 (positive: towards the left of travel) and the speed (B, T) m/s."""
    xp = namespace(joints)
    xz = smooth(ts.xz(joints[:, :, 0]), SMOOTH_S * fps)
    v = ts.gradient(xz) * fps
    a = ts.gradient(v) * fps
    speed = ts.norm(v)
    ahead = v / xp.maximum(speed, ts.const(speed, 1e-6))[..., None]
    left = xp.stack([ahead[..., 1], -ahead[..., 0]], axis=-1)  # facing +Z, +X is to the left
    return ahead, xp.sum(a * left, axis=-1), speed


@_batched
def sideways_lean(joints, fps: float, ahead=None):
    """(B, T) degrees: the torso's (pelvis to neck) lean towards the left of the direction of travel, frame by frame
    in the frame of travel, then smoothed (a vector smoothed in the world would lose its sideways part on a tight
    curve); ``ahead`` (B, T, 2) is :func:`turn_frame`'s, computed when not given."""
    xp = namespace(joints)
    if ahead is None:
        ahead, _, _ = turn_frame(joints, fps)
    left = xp.stack([ahead[..., 1], -ahead[..., 0]], axis=-1)
    up = joints[:, :, NECK] - joints[:, :, 0]
    angle = ts.degrees(ts.atan2(xp.sum(ts.xz(up) * left, axis=-1), up[..., 1]))
    return smooth(angle, SMOOTH_S * fps)


@_batched
def expected_lean(joints, fps: float, share: float = LEAN_SHARE):
    """(B, T) degrees: the lean real people show for this path, ``share * atan(a_lat / g)`` (positive: left), faded
    out below walking speed (:data:`MOVING`)."""
    _, a_lat, speed = turn_frame(joints, fps)
    return _lean_for(a_lat, speed, share)


def _lean_for(a_lat, speed, share: float):
    xp = namespace(a_lat)
    k = lambda v: ts.const(a_lat, v)  # noqa: E731
    moving = ts.smoothstep((speed - k(MOVING[0])) / k(MOVING[1] - MOVING[0]))
    lean = ts.degrees(ts.atan2(a_lat, xp.zeros_like(a_lat) + k(G)))
    return xp.clip(k(share) * lean, -MAX_LEAN_DEG, MAX_LEAN_DEG) * moving


@_batched
def lean_into_turns(joints, fps: float, share: float = LEAN_SHARE):
    """Joints (B, T, 22, 3) metres with the body above the legs turned about the pelvis, about the direction of
    travel, by what it lacks of :func:`expected_lean` (a motion already leaning enough is left as it is). Rigid:
    every joint but the legs' turns with the pelvis; the legs are placed by the cleanup's IK."""
    xp = namespace(joints)
    x = joints
    if share <= 0 or x.shape[1] < 3:
        return x + 0.0
    ahead, a_lat, speed = turn_frame(x, fps)
    want = _lean_for(a_lat, speed, share)
    have = sideways_lean(x, fps, ahead)
    sign = xp.sign(want)
    extra = sign * xp.clip(xp.abs(want) - sign * have, 0.0, None)
    leans = xp.any(xp.abs(extra) > ts.const(extra, 1e-3), axis=1, keepdims=True)  # a motion that lacks no lean is left as it is
    theta = ts.radians(xp.where(leans, extra, xp.zeros_like(extra)))
    # rotation about the axis of travel a = (ax, 0, az); positive theta tips +Y towards the left (az, 0, -ax)
    ax, az = ahead[..., 0:1], ahead[..., 1:2]  # (B, T, 1)
    c, s = xp.cos(theta)[..., None], xp.sin(theta)[..., None]
    rel = x - x[:, :, :1]
    along = rel[..., 0] * ax + rel[..., 2] * az  # component along the axis
    lat = rel[..., 0] * az - rel[..., 2] * ax  # towards the left
    up = rel[..., 1]
    lat2 = c * lat + s * up
    up2 = -s * lat + c * up
    turned = x[:, :, :1] + xp.stack([along * ax + lat2 * az, up2, along * az - lat2 * ax], axis=-1)
    body = np.ones((x.shape[2], 1), dtype=bool)
    body[list(LEG_CHAIN_JOINTS)] = False  # the legs are placed by the cleanup's IK
    body = xp.asarray(body, device=device(x))
    return xp.where(leans[..., None, None] & body, turned, x)


__all__ = ["LEAN_SHARE", "expected_lean", "lean_into_turns", "sideways_lean", "turn_frame"]
