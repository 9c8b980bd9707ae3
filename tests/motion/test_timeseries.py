"""The final stage's building blocks along time: numpy and torch (the graph's path) compute the same thing, and
both equal a plain loop."""

from __future__ import annotations

import numpy as np
import pytest

from stablemofusion.motion import timeseries as ts

torch = pytest.importorskip("torch")


def _last_true_loop(m):
    out = np.full(m.shape, -1)
    for n in range(m.shape[0]):
        last = -1
        for t in range(m.shape[1]):
            last = t if m[n, t] else last
            out[n, t] = last
    return out


@pytest.mark.parametrize("T", [1, 2, 7, 120, 333])
def test_last_and_next_true(T):
    m = np.random.default_rng(T).random((6, T)) < np.linspace(0.0, 1.0, 6)[:, None]
    want = _last_true_loop(m)
    assert np.array_equal(ts.last_true(m), want)
    assert np.array_equal(ts.last_true(torch.from_numpy(m)).numpy(), want)
    nxt = T - 1 - _last_true_loop(m[:, ::-1])[:, ::-1]
    nxt[nxt == T] = T  # none after: T
    nxt = np.where(_last_true_loop(m[:, ::-1])[:, ::-1] < 0, T, nxt)
    assert np.array_equal(ts.next_true(m), nxt)
    assert np.array_equal(ts.next_true(torch.from_numpy(m)).numpy(), nxt)


def test_running_maximum_windows_and_reads():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(3, 50))
    assert np.allclose(ts.cummax(torch.from_numpy(x)).numpy(), np.maximum.accumulate(x, 1))
    v = rng.normal(size=(3, 50, 2))
    for weights in (np.hanning(9)[1:-1], ts.gaussian(10.0, 3.0)):  # a kernel wider than half the motion too
        for edge in (False, True):
            got = ts.window(v, weights, edge)
            r = len(weights) // 2
            pad = np.pad(v, ((0, 0), (r, r), (0, 0)), mode="edge" if edge else "constant")
            want = sum(w * pad[:, j:j + 50] for j, w in enumerate(weights))
            assert np.allclose(got, want, atol=1e-12)
            assert np.allclose(ts.window(torch.from_numpy(v), weights, edge).numpy(), want, atol=1e-12)
    idx = rng.integers(-3, 55, size=(3, 50))
    want = np.take_along_axis(v, np.clip(idx, 0, 49)[..., None], 1)
    assert np.array_equal(ts.at(v, idx), want)
    assert np.array_equal(ts.at(torch.from_numpy(v), torch.from_numpy(idx)).numpy(), want)
    assert np.allclose(ts.gradient(v), np.gradient(v, axis=1))


def test_atan2_in_double_precision_on_tensors():
    rng = np.random.default_rng(2)
    y, x = rng.normal(size=(2, 1000)) * np.array([[1.0], [1e-3]])
    got = ts.atan2(torch.from_numpy(y), torch.from_numpy(x)).numpy()
    assert np.abs(got - np.arctan2(y, x)).max() < 1e-14
