"""The precomputed-coefficient samplers equal the diffusers schedulers on the same noise (1e-4)."""

import pytest
import torch

from stablemofusion.diffusion.schedulers import SAMPLERS, make_sampler, sampler_names, sampler_spec
from stablemofusion.diffusion.sampling import Noise, run_diffusers, run_solver
from stablemofusion.diffusion.solvers import solver_table
from stablemofusion.core.errors import SMFError

FAST = [n for n in sampler_names() if sampler_spec(n).fast]
B, T, D = 3, 24, 8


def _denoiser():
    """A smooth nonlinear x0 predictor that depends on the timestep (stands in for a model)."""
    W = torch.randn(D, D, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 0.3

    def denoise(x, step):
        s = step.t.to(torch.float64)[:, None, None] / 1000
        return torch.tanh(x.double() @ W) * (1 - s) + 0.3 * torch.sin(x.double())

    return denoise


def test_the_engine_has_the_samplers_the_issue_asks_for():
    assert {"ddim", "euler", "euler-karras", "dpmsolver++-karras", "sde-dpmsolver++-karras"} <= set(FAST)


@pytest.mark.parametrize("steps", [1, 2, 5, 10, 25])
@pytest.mark.parametrize("name", FAST)
def test_solver_equals_diffusers(name, steps):
    if steps > 1 and sampler_spec(name).stochastic and not sampler_spec(name).step_noise:
        pytest.skip("its scheduler draws its own step noise (lcm: compared on the same draws in test_distil.py)")
    den = _denoiser()
    sched = make_sampler(name)
    sched.set_timesteps(steps)
    ref = run_diffusers(den, sched, sampler_spec(name), Noise(0, [T] * B, D, torch.device("cpu")), torch.float64, B)
    table = solver_table(name, steps).to("cpu", torch.float64)
    noise = Noise(0, [T] * B, D, torch.device("cpu"))
    x = noise.draw().double() * table.init_sigma
    out = run_solver(den, table, x, noise.draw(steps).double() if table.stochastic else None)
    assert table.stochastic == SAMPLERS[name.removesuffix("-karras")].stochastic
    assert torch.allclose(out, ref, atol=1e-4, rtol=0), float((out - ref).abs().max())


def test_samplers_without_a_fast_form_are_refused():
    with pytest.raises(SMFError, match="no fast"):
        solver_table("pndm", 10)
    with pytest.raises(SMFError, match="at least 1"):
        solver_table("ddim", 0)


def test_the_registry_facts_hold_for_the_installed_diffusers():
    import inspect

    for name, spec in SAMPLERS.items():
        takes = "variance_noise" in inspect.signature(make_sampler(name).step).parameters
        assert not spec.step_noise or takes, name
        assert spec.stochastic or not spec.step_noise
