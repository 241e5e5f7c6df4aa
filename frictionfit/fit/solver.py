"""frictionfit's Levenberg-Marquardt as an optimistix least-squares solver.

``optx.least_squares(fn, BatchedLevenbergMarquardt(), y0)`` solves one problem with
the iteration of :func:`frictionfit.fit._lm.lm_iteration` (Nielsen damping, Marquardt
scaling, MINPACK-like convergence tests); ``fit_trials`` runs it, like any optimistix
least-squares solver, in refilled pools of slots (:mod:`frictionfit.fit._optx`), with
the same arithmetic as ``solve_pool``. ``y0`` must be a 1-D array.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from frictionfit.fit._lm import NONFINITE, RUNNING, LMConfig, _Pool, lm_iteration

__all__ = ["BatchedLevenbergMarquardt"]


class BatchedLevenbergMarquardt(optx.AbstractLeastSquaresSolver):
    """Levenberg-Marquardt with Nielsen's damping and Marquardt scaling.

    Parameters
    ----------
    rtol : float
        Relative step tolerance: converged when every component moves by less than
        ``rtol (1 + |y|)`` (MINPACK's ``xtol``).
    atol : float
        Gradient tolerance: converged when the largest cosine between the residual and
        a Jacobian column falls below it (MINPACK's ``gtol``).
    ftol : float
        Converged when an accepted, nearly undamped step lowers the cost by less than
        this, relatively.
    lambda0 : float
        Damping after the first evaluation.
    norm : callable
        Kept for optimistix's interface; the tests above do not use it.

    Examples
    --------
    >>> import jax.numpy as jnp, optimistix as optx
    >>> fn = lambda y, x: y[0] * (1 - jnp.exp(-y[1] * x)) - 2 * (1 - jnp.exp(-0.5 * x))
    >>> sol = optx.least_squares(fn, BatchedLevenbergMarquardt(), jnp.array([1.0, 1.0]),
    ...                          args=jnp.linspace(0.1, 5, 20))
    >>> [round(float(v), 6) for v in sol.value]
    [2.0, 0.5]
    """

    rtol: float = 1e-8
    atol: float = 1e-10
    ftol: float = 1e-6
    lambda0: float = 1e-3
    norm: Callable = optx.max_norm

    def _config(self) -> LMConfig:
        # optimistix's ``max_steps`` bounds the iterations; the slot never stops on its own
        return LMConfig(ftol=self.ftol, xtol=self.rtol, gtol=self.atol,
                        max_steps=np.iinfo(np.int32).max, lambda0=self.lambda0)

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        if jnp.ndim(y) != 1:
            raise ValueError(f"BatchedLevenbergMarquardt needs a 1-D y0, got shape "
                             f"{jnp.shape(y)}")
        p, dtype = y.shape[0], y.dtype
        pool = _Pool(u=y, cand=y, cost=jnp.array(jnp.inf, dtype),
                     jtj=jnp.zeros((p, p), dtype), grad=jnp.zeros(p, dtype),
                     scale=jnp.zeros(p, dtype), lam=jnp.array(self.lambda0, dtype),
                     steps=jnp.array(0), code=jnp.array(RUNNING))
        return pool, jax.tree_util.tree_map(jnp.zeros_like, aux_struct)

    def step(self, fn, y, args, options, state, tags):
        pool, _ = state

        def residual(u):
            r, aux = fn(u, args)
            return r, (r, aux)

        jac, (r, aux) = jax.jacfwd(residual, has_aux=True)(pool.cand)
        pool = lm_iteration(pool, (0.5 * r @ r, jac.T @ jac, jac.T @ r), self._config())
        return pool.u, (pool, aux), aux

    def terminate(self, fn, y, args, options, state, tags):
        pool, _ = state
        result = optx.RESULTS.where(pool.code == NONFINITE,
                                    optx.RESULTS.nonlinear_divergence,
                                    optx.RESULTS.successful)
        return pool.code != RUNNING, result

    def postprocess(self, fn, y, aux, args, options, state, tags, result
                    ) -> tuple[Any, Any, dict[str, Any]]:
        pool, _ = state
        return pool.u, aux, {"steps": pool.steps}

