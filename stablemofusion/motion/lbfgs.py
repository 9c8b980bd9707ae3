"""A small L-BFGS minimiser in numpy (the rigid body's pose optimisations run it; no torch, no scipy).

Facts used (Nocedal & Wright, Numerical Optimization, ch. 7 and 3): the two-loop recursion over the last
``history`` pairs (s, y) with the initial Hessian scaled by s.y / y.y; a pair is kept only when s.y > 0; a
backtracking line search on the Armijo condition from the step 1 (the first iteration from min(1, 1 / |g|_1),
as PyTorch's L-BFGS starts); at most ``max_evals`` function evaluations in all.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

Objective = Callable[[np.ndarray], tuple[float, np.ndarray]]  # x (n,) -> (f(x), gradient (n,))
ARMIJO = 1e-4  # sufficient decrease
SHRINK = 0.5  # backtracking factor
TOLERANCE_GRAD = 1e-7  # stop when max |g| is this small


def lbfgs(f: Objective, x0: np.ndarray, iterations: int, *, history: int = 10,
          max_evals: int | None = None) -> np.ndarray:
    """Minimise ``f`` from ``x0`` (float64) with at most ``iterations`` L-BFGS iterations and ``max_evals``
    evaluations (default: 1.25 per iteration, as PyTorch's). Returns the best point found."""
    x = np.array(x0, dtype=np.float64)
    value, g = f(x)
    evals, budget = 1, max_evals if max_evals is not None else int(iterations * 1.25)
    s_hist: list[np.ndarray] = []
    y_hist: list[np.ndarray] = []
    for it in range(iterations):
        if np.abs(g).max() <= TOLERANCE_GRAD or evals >= budget:
            break
        d = -_two_loop(g, s_hist, y_hist)
        slope = float(g @ d)
        if slope >= 0:  # not a descent direction (curvature lost): restart from steepest descent
            s_hist.clear()
            y_hist.clear()
            d, slope = -g, -float(g @ g)
        step = min(1.0, 1.0 / np.abs(g).sum()) if it == 0 else 1.0
        while True:
            x_new = x + step * d
            v_new, g_new = f(x_new)
            evals += 1
            if v_new <= value + ARMIJO * step * slope or evals >= budget:
                break
            step *= SHRINK
        if not v_new <= value:  # the budget ran out without a decrease: keep the best point
            break
        s, y = x_new - x, g_new - g
        if float(s @ y) > 1e-10:
            s_hist.append(s)
            y_hist.append(y)
            if len(s_hist) > history:
                s_hist.pop(0)
                y_hist.pop(0)
        x, value, g = x_new, v_new, g_new
    return x


def _two_loop(g: np.ndarray, s_hist: list[np.ndarray], y_hist: list[np.ndarray]) -> np.ndarray:
    """H g for the L-BFGS inverse-Hessian estimate of the pairs (s, y)."""
    q = g.copy()
    alphas = []
    for s, y in zip(reversed(s_hist), reversed(y_hist)):
        a = float(s @ q) / float(y @ s)
        alphas.append(a)
        q -= a * y
    if s_hist:
        q *= float(s_hist[-1] @ y_hist[-1]) / float(y_hist[-1] @ y_hist[-1])
    for (s, y), a in zip(zip(s_hist, y_hist), reversed(alphas)):
        b = float(y @ q) / float(y @ s)
        q += (a - b) * s
    return q


__all__ = ["lbfgs"]
