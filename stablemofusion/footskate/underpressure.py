"""Our port of the UnderPressure vGRF network (Mourot et al., SCA 2022) and the glue to feed it our motions.

The network reads global positions of a 23-joint skeleton (metres, Z up, 100 fps) and predicts the vertical
ground reaction force on 16 insole cells per foot, as a fraction of body weight (foot 0 = left).
Weights are NOT part of this package: the user supplies UnderPressure's ``pretrained.tar``, which is under a
non-commercial research licence (InterDigital); so is every output computed with it.

Conventions: our 22-joint HumanML3D motions are Y up, face +Z, left towards +X, 20 fps; UnderPressure's
skeleton is Z up, faces +X, left towards +Y. :func:`to_underpressure_frame` maps one onto the other
(a proper rotation), :func:`retarget_22_to_23` rebuilds the 23 joints from ours.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..core.errors import SMFError
from ..motion.arrays import numpy_edge, to_torch
from ..motion.resample import resample
from ..motion.rotation import qrot

UP_FPS = 100.0
UP_JOINTS = (
    "pelvis", "spine_1", "spine_2", "spine_3", "spine_4", "neck", "head",
    "right_clavicle", "right_shoulder", "right_elbow", "right_wrist",
    "left_clavicle", "left_shoulder", "left_elbow", "left_wrist",
    "right_hip", "right_knee", "right_ankle", "right_foot",
    "left_hip", "left_knee", "left_ankle", "left_foot",
)
UP_PARENTS = (-1, 0, 1, 2, 3, 4, 5, 4, 7, 8, 9, 4, 11, 12, 13, 0, 15, 16, 17, 0, 19, 20, 21)
# Rest pose of UnderPressure's skeleton (root-relative, metres, Z up, facing +X), read off its data files.
UP_REST = np.array([
    [0.0, 0.0, 0.0], [-0.011005, 0.0, 0.099043], [-0.011005, 0.0, 0.20955], [-0.010891, 0.0, 0.31042],
    [-0.010778, 0.0, 0.41118], [-0.010778, 0.0, 0.55138], [-0.011022, 0.0, 0.64516],
    [-0.010778, -0.029549, 0.4897], [-0.010778, -0.16564, 0.4897], [-0.010778, -0.45271, 0.4897],
    [-0.010721, -0.68882, 0.4897], [-0.010778, 0.029549, 0.4897], [-0.010778, 0.16564, 0.4897],
    [-0.010778, 0.45271, 0.4897], [-0.010721, 0.68882, 0.4897], [3.0e-05, -0.080975, -0.00026602],
    [5.6e-05, -0.080975, -0.42639], [0.000102, -0.080975, -0.84216], [0.16932, -0.080975, -0.91693],
    [3.2e-05, 0.080975, -0.00028902], [5.9e-05, 0.080975, -0.42641], [0.000104, 0.080975, -0.84218],
    [0.16932, 0.080975, -0.91695],
])
FEET = ("left", "right")  # output foot order
LICENCE_NOTE = ("UnderPressure (c) InterDigital, Limited Software Evaluation License: non-commercial research use "
                "only. Weights, and any model distilled from them, inherit this restriction.")


class UnderPressureNet(nn.Module):
    """(B, T, 23, 3) global joint positions (m, Z up, 100 fps) -> (B, T, 2, 16) vGRF (body weight).

    Parameter names match the ``nn.Sequential`` state dict of ``pretrained.tar`` (keys 3..22).
    """

    def __init__(self, joints: int = 23, dropout: float = 0.2):
        super().__init__()
        chans = (3 * joints, 128, 128, 256, 256)
        layers: dict[str, nn.Module] = {}
        for i, key in enumerate((3, 6, 9, 12)):
            layers[str(key - 1)] = nn.Dropout(dropout)
            layers[str(key)] = nn.Conv1d(chans[i], chans[i + 1], 7, padding=3, padding_mode="replicate")
            layers[str(key + 1)] = nn.ELU()
        for key in (16, 19):
            layers[str(key - 1)] = nn.Dropout(dropout)
            layers[str(key)] = nn.Linear(256, 256)
            layers[str(key + 1)] = nn.ELU()
        layers["22"] = nn.Linear(256, 32, bias=False)
        self.layers = nn.ModuleDict(layers)

    def forward(self, joints: torch.Tensor) -> torch.Tensor:
        B, T = joints.shape[:2]
        h = joints.reshape(B, T, -1).transpose(1, 2)  # time on the convolution axis
        for key in range(2, 14):
            h = self.layers[str(key)](h)
        h = h.transpose(1, 2)
        for key in range(15, 21):
            h = self.layers[str(key)](h)
        return nn.functional.softplus(self.layers["22"](h)).reshape(B, T, 2, 16)

    def load_sequential_state(self, state: dict) -> None:
        """Load a ``torch.nn.Sequential`` state dict (keys like '3.weight')."""
        self.layers.load_state_dict({k: v for k, v in state.items()}, strict=True)


def load_underpressure(path: str | Path) -> UnderPressureNet:
    """Load the user's UnderPressure ``pretrained.tar`` into :class:`UnderPressureNet` (eval mode, CPU).

    Raises SMFError when the file is missing or holds something else. Non-commercial licence applies.
    """
    path = Path(path)
    if not path.is_file():
        raise SMFError(f"UnderPressure weights not found: {path} (get pretrained.tar from the UnderPressure "
                       "release; it is non-commercial and not shipped)")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - torch raises many types for broken files
        raise SMFError(f"{path}: not a readable torch file ({e.__class__.__name__})") from None
    state = blob.get("model", blob) if isinstance(blob, dict) else None
    net = UnderPressureNet()
    try:
        net.load_sequential_state(state)
    except Exception:  # noqa: BLE001
        raise SMFError(f"{path}: not an UnderPressure state dict (expected keys 3..22 of an nn.Sequential, "
                       "Conv1d 69->128->128->256->256, Linear 256->256->256->32)") from None
    return net.eval()


@numpy_edge
def forward_kinematics_23(angles, skeleton, trajectory):
    """UnderPressure FK: global quaternions (F, 23, 4) w,x,y,z, rest positions (23, 3) or (1, 23, 3),
    root translation (F, 3) or (F, 1, 3) -> global positions (F, 23, 3). numpy or torch."""
    rest = skeleton.reshape(23, 3)
    traj = trajectory.reshape(-1, 1, 3)
    frames = angles.shape[0]
    parts = [rest[0].expand(frames, 3)]
    for j in range(1, 23):
        p = UP_PARENTS[j]
        parts.append(parts[p] + qrot(angles[:, p], (rest[j] - rest[p]).expand(frames, 3)))
    return torch.stack(parts, 1) + traj


def to_underpressure_frame(x):
    """Our axes (X left, Y up, Z forward) -> UnderPressure's (X forward, Y left, Z up), (..., 3)."""
    return x[..., [2, 0, 1]]


def from_underpressure_frame(x):
    """Inverse of :func:`to_underpressure_frame`."""
    return x[..., [1, 2, 0]]


# Each UnderPressure joint from ours (HumanML3D indices): the spine chain pelvis-spine1-spine2-spine3-neck is
# resampled at UnderPressure's rest arc-length fractions; everything else maps one to one.
_DIRECT = {0: 0, 5: 12, 6: 15, 7: 14, 8: 17, 9: 19, 10: 21, 11: 13, 12: 16, 13: 18, 14: 20,
           15: 2, 16: 5, 17: 8, 18: 11, 19: 1, 20: 4, 21: 7, 22: 10}
_SPINE = (0, 3, 6, 9, 12)
# A planted foot of our corpus has its ankle->toe bone about 36 deg below horizontal (ankle ~9 cm above the
# toe over a 14-15 cm bone), UnderPressure's rest foot about 24 deg (7.5 cm over 18.5 cm): raise ours by 12.5.
FOOT_PITCH_OFFSET = float(np.deg2rad(12.5))


def _spine_fractions() -> np.ndarray:
    seg = np.linalg.norm(np.diff(UP_REST[[0, 1, 2, 3, 4, 5]], axis=0), axis=-1)
    return np.cumsum(seg)[:4] / seg.sum()


@numpy_edge
def retarget_22_to_23(joints22, *, bone_lengths: bool = True):
    """Our joints (..., T, 22, 3) (m, Y up) -> UnderPressure joints (..., T, 23, 3) (m, Z up). numpy or torch.

    Spine joints are placed along our spine polyline at UnderPressure's rest arc-length fractions; with
    ``bone_lengths`` every bone then gets UnderPressure's rest length (directions kept), the root path is
    scaled by the leg-length ratio and the result is put back on the floor our motion stands on (the lowest
    foot joint keeps its height above y = 0, shifted by the rest foot-joint height difference).
    Differentiable for torch inputs.
    """
    x = to_underpressure_frame(joints22)
    spine = x[..., list(_SPINE), :]  # (..., T, 5, 3)
    step = spine[..., 1:, :] - spine[..., :-1, :]
    seg = _length(step)  # (..., T, 4) metres
    cum = torch.cumsum(seg, -1)
    starts = torch.cat([cum[..., :1] * 0, cum[..., :-1]], -1)
    # every spine joint k at once: its arc length along the chain, its position on each of the 4 segments
    target = cum[..., -1:] * torch.as_tensor(_spine_fractions(), dtype=x.dtype, device=x.device)  # (..., T, 4)
    w = (target[..., :, None] - starts[..., None, :]) / seg[..., None, :].clamp(min=1e-8)  # (..., T, k, segment)
    inside = (w >= 0) & ((w <= 1) | _LAST_SEGMENT.to(x.device))
    cand = spine[..., None, :-1, :] + w.clamp(0, 1)[..., None] * step[..., None, :, :]  # (..., T, k, segment, 3)
    pt = spine[..., None, 0, :].expand(cand.shape[:-2] + (3,))
    for s in range(4):  # the last segment holding the target arc length wins
        pt = torch.where(inside[..., s, None], cand[..., s, :], pt)
    direct = x[..., list(_DIRECT.values()), :]
    y = torch.cat([direct[..., :1, :], pt, direct[..., 1:, :]], -2)  # _DIRECT lists joints 0, 5..22 in order
    if not bone_lengths:
        return y
    rest = torch.as_tensor(UP_REST, dtype=y.dtype, device=y.device)
    lens = _length(rest[1:] - rest[list(UP_PARENTS[1:])])  # (22,) bone into joints 1..22
    leg_src = _length(y[..., 16, :] - y[..., 15, :]) + _length(y[..., 17, :] - y[..., 16, :])
    scale = float(lens[15] + lens[16]) / leg_src.mean(-1, keepdim=True)
    d = y[..., 1:, :] - y[..., list(UP_PARENTS[1:]), :]  # (..., T, 22, 3) bones into joints 1..22
    feet = _pitch_up(d[..., [17, 21], :], FOOT_PITCH_OFFSET)  # our flat-foot ankle->toe bone points further down
    d = torch.cat([d[..., :17, :], feet[..., :1, :], d[..., 18:21, :], feet[..., 1:, :]], -2)
    bones = d / _length(d)[..., None].clamp(min=1e-8) * lens[:, None]
    z = y[..., :1, :] * scale[..., None, None] + torch.einsum("jb,...bc->...jc", _ANCESTORS.to(bones), bones)
    # floor: keep our lowest foot height (ours: min over the toe joints ~ floor contact) -> same for theirs
    shift = _lowest(x[..., [10, 11], 2]) - _lowest(z[..., [18, 22], 2])  # (..., 1, 1)
    zero = torch.zeros_like(shift)
    return z + torch.stack([zero, zero, shift], -1)


def _ancestors() -> torch.Tensor:
    """(23, 22): 1 where the bone into joint b + 1 lies on the path from the root to joint j."""
    a = torch.zeros(23, 22, dtype=torch.float64)
    for j in range(1, 23):
        a[j] = a[UP_PARENTS[j]]
        a[j, j - 1] = 1.0
    return a


_ANCESTORS = _ancestors()
_LAST_SEGMENT = torch.tensor([False, False, False, True])


def _pitch_up(d: torch.Tensor, angle: float) -> torch.Tensor:
    """Raise the pitch of Z-up direction vectors (..., 3) by ``angle`` radians, keeping their heading."""
    hx, hy, hz = d.unbind(-1)
    hn = torch.sqrt(hx * hx + hy * hy + 1e-12)
    pitch = torch.atan2(hz, hn) + angle
    n = torch.sqrt(hn * hn + hz * hz)
    c = torch.cos(pitch) * n / hn
    return torch.stack([hx * c, hy * c, torch.sin(pitch) * n], -1)


def _length(v: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (...) Euclidean length."""
    return torch.linalg.vector_norm(v, dim=-1)


def _lowest(h: torch.Tensor) -> torch.Tensor:
    """Minimum over time and the listed joints (..., T, K) -> (..., 1, 1)."""
    return h.amin(dim=(-2, -1), keepdim=True)


@numpy_edge
def resample_time(x, src_fps: float, dst_fps: float):
    """Linear resampling of a motion over the same duration: along axis -3 of (..., T, J, C) (axis 0 of
    (T,) or (T, C)), from ``src_fps`` to ``dst_fps``. numpy or torch, differentiable for torch."""
    axis = x.dim() - 3 if x.dim() >= 3 else 0
    T = x.shape[axis]
    if abs(src_fps - dst_fps) < 1e-9 or T < 2:
        return x
    n = int(np.floor((T - 1) / src_fps * dst_fps + 1e-9)) + 1
    pos = torch.arange(n, dtype=torch.float64, device=x.device) / dst_fps * src_fps
    i0 = torch.clamp(pos.floor().long(), max=T - 2)
    w = (pos - i0).to(x.dtype).reshape((-1,) + (1,) * (x.dim() - axis - 1))
    return x.index_select(axis, i0) * (1 - w) + x.index_select(axis, i0 + 1) * w


@torch.no_grad()
def vgrf_from_joints23(net: UnderPressureNet, joints23) -> np.ndarray:
    """UnderPressure joints (T, 23, 3) at 100 fps -> vGRF (T, 2, 16) (body weight, foot 0 = left)."""
    x = to_torch(joints23, torch.float32)[None]
    return net(x)[0].double().numpy()


def vgrf_from_joints22(net: UnderPressureNet, joints22: np.ndarray, fps: float = 20.0) -> np.ndarray:
    """Our joints (T, 22, 3) at ``fps`` -> vGRF (T, 2, 16) at ``fps``: retarget, upsample to 100 fps,
    run the network, resample back. Non-commercial licence (UnderPressure weights)."""
    j23 = retarget_22_to_23(np.asarray(joints22, dtype=np.float64))
    up = resample(j23, fps, UP_FPS)
    f = vgrf_from_joints23(net, up)
    back = resample(f, UP_FPS, fps)
    if len(back) < len(joints22):  # the last frame may fall between 100-fps samples
        back = np.concatenate([back, np.repeat(back[-1:], len(joints22) - len(back), 0)])
    return back[:len(joints22)]


def load_s1(path: str | Path) -> dict[str, np.ndarray]:
    """An UnderPressure data file (e.g. S1_Hopping.pth) -> dict with 'joints' (F, 23, 3) from FK and,
    when present, 'forces' (F, 2, 16) and 'contacts' (F, 2, 2) as numpy arrays."""
    path = Path(path)
    if not path.is_file():
        raise SMFError(f"no such file: {path}")
    d = torch.load(path, map_location="cpu", weights_only=False)
    out = {"joints": forward_kinematics_23(d["angles"].double(), d["skeleton"].double(),
                                           d["trajectory"].double()).numpy()}
    for k in ("forces", "contacts"):
        if k in d:
            out[k] = d[k].numpy()
    return out


class TeacherOn22(nn.Module):
    """UnderPressure on our joints: (B, T, 22, 3) at ``fps`` -> (B, T, 2, 16) at ``fps``, differentiable
    (retarget, resample to 100 fps, network, resample back). Non-commercial licence."""

    def __init__(self, net: UnderPressureNet, fps: float = 20.0):
        super().__init__()
        self.net = net.eval()
        self.fps = fps

    def forward(self, joints22: torch.Tensor) -> torch.Tensor:
        T = joints22.shape[1]
        up = resample_time(retarget_22_to_23(joints22), self.fps, UP_FPS)
        f = self.net(up)
        back = resample_time(f, UP_FPS, self.fps)
        if back.shape[1] < T:
            back = torch.cat([back, back[:, -1:].expand(-1, T - back.shape[1], -1, -1)], 1)
        return back[:, :T]


# Our spine joints (spine1, spine2, spine3) at their rest arc-length fractions of pelvis -> neck (HumanML3D's
# target bone lengths 0.1316, 0.1432, 0.0574 out of 0.5516 m).
_OUR_SPINE_FRACTIONS = (0.2385, 0.4981, 0.6022)
_FROM_UP = {0: 0, 1: 19, 2: 15, 4: 20, 5: 16, 7: 21, 8: 17, 10: 22, 11: 18, 12: 5, 13: 11, 14: 7, 15: 6,
            16: 12, 17: 8, 18: 13, 19: 9, 20: 14, 21: 10}


def retarget_23_to_22(joints23: np.ndarray, fps: float = UP_FPS, dst_fps: float = 20.0) -> np.ndarray:
    """UnderPressure joints (T, 23, 3) (m, Z up) at ``fps`` -> our joints (T', 22, 3) (m, Y up) at
    ``dst_fps``: one-to-one joints, our three spine joints on their spine polyline; heights kept."""
    x = from_underpressure_frame(np.asarray(joints23, dtype=np.float64))
    chain = x[:, [0, 1, 2, 3, 4, 5]]
    seg = np.linalg.norm(np.diff(chain, axis=1), axis=-1)
    cum = np.concatenate([np.zeros((len(x), 1)), np.cumsum(seg, -1)], -1)
    out = np.zeros((len(x), 22, 3))
    for ours, theirs in _FROM_UP.items():
        out[:, ours] = x[:, theirs]
    for ours, f in zip((3, 6, 9), _OUR_SPINE_FRACTIONS):
        target = cum[:, -1] * f
        s = np.clip((cum[:, 1:] < target[:, None]).sum(-1), 0, 4)
        r = np.arange(len(x))
        w = ((target - cum[r, s]) / np.maximum(seg[r, s], 1e-8))[:, None]
        out[:, ours] = chain[r, s] + w * (chain[r, s + 1] - chain[r, s])
    return resample(out, fps, dst_fps)
