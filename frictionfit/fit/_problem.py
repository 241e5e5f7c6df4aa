"""The least-squares problem of one trial: masked residual, normal equations, Jacobian.

Per-trial data is a tuple ``(y, mask, drive_input, direction, t0, dt, base)``:
force samples (N, NaN replaced by 0), the finite-sample mask, the drive
(``(t_out, t_back)`` in s, or a displacement in mm per sample), the channel's
sign, the first sample time and the sample interval (s), and ``base``, the full
unconstrained parameter vector whose entries outside ``free`` stay fixed.
Functions are cached per (model, free set) so jitted callers never recompile
for a second batch of the same shape.
"""

from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp

from frictionfit.models import ContactModel

__all__ = ["jacobian_fn", "normal_fn", "residual_fn"]


@lru_cache(maxsize=64)
def residual_fn(model: ContactModel, free: tuple[int, ...]):
    """``residual(u_free, data) -> (n,)``: prediction minus data, zero where masked."""
    free_idx = jnp.asarray(free)

    def residual(u_free, data):
        y, mask, drive_input, direction, t0, dt, base = data
        u = base.at[free_idx].set(u_free)
        t = t0 + dt * jnp.arange(y.shape[-1], dtype=y.dtype)
        pred = model.predict(u, t, drive_input, direction)
        return jnp.where(mask, pred - y, 0.0)

    return residual


@lru_cache(maxsize=64)
def normal_fn(model: ContactModel, free: tuple[int, ...]):
    """``normal(u_free, data) -> (0.5 |r|^2, J^T J, J^T r)`` by one forward-mode pass."""
    residual = residual_fn(model, free)

    def normal(u_free, data):
        def both(u):
            r = residual(u, data)
            return r, r

        jac, r = jax.jacfwd(both, has_aux=True)(u_free)
        return 0.5 * r @ r, jac.T @ jac, jac.T @ r

    return normal


@lru_cache(maxsize=64)
def jacobian_fn(model: ContactModel, free: tuple[int, ...]):
    """Jitted, vmapped ``(u_free, data) -> (r, J^T J)`` for the statistics at the optimum."""
    residual = residual_fn(model, free)

    def one(u_free, data):
        def both(u):
            r = residual(u, data)
            return r, r

        jac, r = jax.jacfwd(both, has_aux=True)(u_free)
        return r, jac.T @ jac

    return jax.jit(jax.vmap(one))
