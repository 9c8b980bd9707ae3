"""The portable noise: a standard normal, independent across seeds, streams and draws, the same for any length,
and the same numbers in JavaScript (assets/runtime/noise.js) as in numpy."""

import importlib.util
import json
import shutil
import subprocess
from importlib import resources

import numpy as np
import pytest

from stablemofusion.core.noise import (LENGTH_DRAW, batch_noise, draw_key, draws, length_level, mix, noise, normal,
                                       uniform)


def test_mix_is_the_published_bijection_on_known_values():
    # lowbias32 on 0 and 1 (checked against the JavaScript twin below as well)
    assert int(mix(np.array([0], np.uint32))[0]) == 0
    x = np.arange(1 << 16, dtype=np.uint32)
    assert len(np.unique(mix(x))) == len(x)


def test_values_are_standard_normal():
    x = normal(123, 1_000_000).astype(np.float64)
    assert abs(x.mean()) < 0.005 and abs(x.std() - 1) < 0.005
    assert abs((x ** 3).mean()) < 0.02 and abs((x ** 4).mean() - 3) < 0.05
    assert abs((np.abs(x) < 1).mean() - 0.6827) < 0.002
    assert np.abs(x).max() < 5.8


def test_draws_are_uncorrelated_across_seeds_streams_draws_and_neighbours():
    n = 200_000
    base = normal(5, n)
    others = [normal(6, n), normal(5, n, stream=1), normal(5, n, draw=1), normal(5 + 2**32, n)]
    for o in others:
        assert abs(np.corrcoef(base, o)[0, 1]) < 0.01
    assert abs(np.corrcoef(base[:-1], base[1:])[0, 1]) < 0.01
    assert abs(np.corrcoef(base[0::2], base[1::2])[0, 1]) < 0.01  # the two halves of a Box-Muller pair


def test_an_items_frames_do_not_depend_on_its_length_or_its_batch():
    long, short = noise(9, 50, 7), noise(9, 21, 7)
    np.testing.assert_array_equal(long[:21], short)
    batch = batch_noise([4, 9], [30, 21], 7)
    np.testing.assert_array_equal(batch[1, :21], short)
    assert not batch[1, 21:].any()
    one_seed = batch_noise(9, [21, 21], 7)  # one seed for the call: item k draws from stream k
    np.testing.assert_array_equal(one_seed[0], short)
    np.testing.assert_array_equal(one_seed[1], noise(9, 21, 7, stream=1))


def test_seeds_out_of_range_are_refused():
    with pytest.raises(ValueError):
        draw_key(2**53)
    with pytest.raises(ValueError):
        draw_key(-1)


def test_a_draws_uniform_is_uniform_and_its_own():
    u = np.array([uniform(s, stream=k, draw=d) for s in range(2000) for k in range(3) for d in (0, LENGTH_DRAW)])
    assert 0 < u.min() and u.max() < 1 and abs(u.mean() - 0.5) < 0.01 and abs(u.var() - 1 / 12) < 0.005
    assert np.histogram(u, 10, (0, 1))[0].min() > 0.9 * len(u) / 10
    assert len(np.unique(u)) > 0.99 * len(u)
    # the definition: the first word of the draw's pair 0
    a = int(mix(np.array([int(mix(np.array([0], np.uint32))[0]) ^ draw_key(7, 1, 3)], np.uint32))[0])
    assert uniform(7, stream=1, draw=3) == ((a >> 8) + 0.5) / 2**24
    assert length_level(7, 1) == uniform(7, stream=1, draw=LENGTH_DRAW) != uniform(7, stream=1, draw=0)


@pytest.mark.skipif(shutil.which("node") is None, reason="needs Node.js for the JavaScript twin")
def test_javascript_gives_the_same_numbers(tmp_path):
    js = resources.files("stablemofusion") / "assets" / "runtime" / "noise.js"
    cases = [(0, 0, 0, 80, 263), (2**53 - 1, 3, 2, 5, 7), (2147853511, 31, 9, 13, 263), (123456789012345, 0, 1, 1, 3)]
    script = tmp_path / "run.mjs"
    script.write_text(f"import {{ noise, drawKey, uniform }} from {json.dumps(js.as_uri())};\n"
                      f"const cases = {json.dumps(cases)};\n"
                      "console.log(JSON.stringify(cases.map(([s, st, d, f, n]) => "
                      "({key: drawKey(s, st, d), values: Array.from(noise(s, f, n, {stream: st, draw: d})), "
                      f"uniform: uniform(s, {{stream: st, draw: d}}), length: uniform(s, {{stream: st, draw: {LENGTH_DRAW}}})}}))));\n")
    out = json.loads(subprocess.run(["node", str(script)], capture_output=True, text=True, check=True,
                                    timeout=60).stdout)
    for (s, st, d, f, n), got in zip(cases, out):
        assert got["key"] == draw_key(s, st, d)
        assert got["uniform"] == uniform(s, stream=st, draw=d) and got["length"] == length_level(s, st)
        want = noise(s, f, n, stream=st, draw=d).ravel()
        js_values = np.asarray(got["values"], dtype=np.float32)
        assert js_values.shape == want.shape
        ulps = np.abs(js_values.view(np.int32).astype(np.int64) - want.view(np.int32).astype(np.int64))
        assert ulps.max() <= 1, (s, st, d, int(ulps.max()))


def _ulps(got, want) -> np.ndarray:
    return np.abs(np.asarray(got).view(np.int32).astype(np.int64) - want.view(np.int32).astype(np.int64))


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not (importlib.util.find_spec("torch") and __import__("torch").cuda.is_available()), reason="needs a CUDA device"))])
def test_torch_makes_the_same_numbers_where_the_model_runs(device):
    torch = pytest.importorskip("torch")
    like = torch.empty(0, device=device)
    for seed, lengths, indices in [(0, [196], range(3)), (2**53 - 1, [50, 7, 33], [0, 9]),
                                   ([3, 2**40 + 1, 0], [12, 40, 40], [1]), (7, [1, 2], [0])]:
        want = draws(seed, lengths, 263, indices)
        got = draws(seed, lengths, 263, indices, like=like)
        assert got.device.type == device and got.dtype == torch.float32 and tuple(got.shape) == want.shape
        # the same float32 numbers: float64 sin/cos/log may differ by an ulp between libraries and CPUs, which
        # rounding to float32 hides but for a value that falls on a float32 rounding boundary (one float32 ulp)
        assert _ulps(got.cpu().numpy(), want).max() <= 1
    mixed = mix(torch.arange(1 << 16, dtype=torch.int64, device=device))  # the words of a tensor: int64 in [0, 2**32)
    np.testing.assert_array_equal(mixed.cpu().numpy(), mix(np.arange(1 << 16, dtype=np.uint32)).astype(np.int64))


def test_a_sampling_call_draws_the_portable_noise_on_its_device():
    torch = pytest.importorskip("torch")
    from stablemofusion.diffusion.sampling import Noise

    noise_of_call = Noise([4, 9], [30, 21], 7, torch.device("cpu"))
    first, rest = noise_of_call.draw(), noise_of_call.draw(2)
    assert tuple(first.shape) == (2, 30, 7) and tuple(rest.shape) == (2, 2, 30, 7)
    np.testing.assert_array_equal(first.numpy(), batch_noise([4, 9], [30, 21], 7))
    np.testing.assert_array_equal(rest.numpy(), draws([4, 9], [30, 21], 7, [1, 2]))


def test_a_large_batch_is_made_a_few_items_at_a_time_with_the_same_numbers(monkeypatch):
    import stablemofusion.core.noise as module

    want = draws(11, [20, 19, 18, 20, 5], 263, [0, 2])
    monkeypatch.setattr(module, "CHUNK", 263 * 20 * 2)  # two items a chunk
    got = draws(11, [20, 19, 18, 20, 5], 263, [0, 2])
    np.testing.assert_array_equal(got, want)
    assert not got[:, 4, 5:].any() and got[:, 4, :5].all()
    assert draws(11, [], 263, [0]).shape == (1, 0, 0, 263) and draws(11, [3], 263, []).shape == (0, 1, 3, 263)


def test_numpy_without_an_array_api_of_its_own_gives_the_same_numbers(monkeypatch):
    """Blender's numpy 1.x has no array-API namespace: the compatibility layer's numpy takes its place."""
    import stablemofusion.motion.arrays as arrays

    want = draws([5, 6], [30, 21], 263, [0, 3])
    monkeypatch.setattr(arrays, "_NUMPY_IS_ARRAY_API", False)
    np.testing.assert_array_equal(draws([5, 6], [30, 21], 263, [0, 3]), want)
