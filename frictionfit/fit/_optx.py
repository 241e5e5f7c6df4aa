"""optimistix least-squares solvers (LM, dogleg, Gauss-Newton), vmapped in rounds.

A vmapped while-loop runs every trial of a chunk until the slowest finishes, so
solves run in *rounds* of ``steps_per_round`` steps: after each round only the
unconverged trials are re-batched (same chunk shape, so nothing recompiles) and
restarted from where they stopped. Forward-mode Jacobians (few parameters,
thousands of residuals). Kept for comparison and as the issue's reference path;
the default ``solver="lm"`` is the faster batched LM of :mod:`frictionfit.fit._lm`.
"""

from __future__ import annotations

from functools import lru_cache

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from frictionfit.errors import FitError
from frictionfit.fit._numerics import pad_rows
from frictionfit.fit._problem import residual_fn
from frictionfit.models import ContactModel

__all__ = ["OPTX_SOLVERS", "solve_rounds"]

OPTX_SOLVERS = ("optx-lm", "dogleg", "gauss-newton")


def _solver(name: str, rtol: float, atol: float):
    if name == "optx-lm":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    if name == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol)
    if name == "gauss-newton":
        return optx.GaussNewton(rtol=rtol, atol=atol)
    raise FitError(f"unknown solver {name!r}; choose from {('lm', *OPTX_SOLVERS)}")


@lru_cache(maxsize=64)
def _chunk_solver(model: ContactModel, free: tuple[int, ...], solver: str, rtol: float,
                  atol: float, steps: int):
    """A jitted, vmapped solve of one chunk; cached so a second batch never recompiles."""
    residual = residual_fn(model, free)
    opt = _solver(solver, rtol, atol)

    def one(u0, data):
        sol = optx.least_squares(residual, opt, u0, args=data, max_steps=steps, throw=False,
                                 options={"jac": "fwd"})
        # A whole Solution cannot leave vmap; return plain arrays.
        return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]

    return eqx.filter_jit(jax.vmap(one))


def solve_rounds(model: ContactModel, free: tuple[int, ...], u0: np.ndarray, data, solver: str,
                 rtol: float, atol: float, max_steps: int, steps_per_round: int,
                 chunk_size: int):
    """Fit every trial with an optimistix solver; returns ``(u, converged, steps)``."""
    _solver(solver, rtol, atol)  # unknown names fail here, before any compilation
    n_trials = u0.shape[0]
    steps_per_round = min(steps_per_round, max_steps)
    solve = _chunk_solver(model, free, solver, rtol, atol, steps_per_round)
    u = u0.copy()
    converged = np.zeros(n_trials, dtype=bool)
    steps = np.zeros(n_trials, dtype=np.int64)
    active = np.arange(n_trials)
    while active.size:
        for start in range(0, active.size, chunk_size):
            idx = active[start:start + chunk_size]
            rows = pad_rows(idx, chunk_size)
            chunk = jax.tree_util.tree_map(lambda a, r=rows: jnp.asarray(a[r]), data)
            u_new, ok, nst = solve(jnp.asarray(u[rows]), chunk)
            u[idx] = np.asarray(u_new)[: idx.size]
            converged[idx] = np.asarray(ok)[: idx.size]
            steps[idx] += np.asarray(nst)[: idx.size]
        active = active[~converged[active] & (steps[active] < max_steps)
                        & np.all(np.isfinite(u[active]), axis=1)]
    return u, converged, steps
