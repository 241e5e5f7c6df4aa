"""The least-squares problem of one trial: masked residual and its Jacobian.

Per-trial data is a tuple ``(y, mask, drive_input, direction, t0, dt, base, noise)``:
force samples (N, NaN replaced by 0), the finite-sample mask, the drive
(``(t_out, t_back)`` in s, or a displacement in mm per sample), the channel's
sign, the first sample time and the sample interval (s), ``base``, the full
unconstrained parameter vector whose entries outside ``free`` stay fixed, and
``noise``, the trial's noise sd (N) estimated before the fit (:func:`noise_scale`).

The residual vector is the ``n_samples`` data residuals followed by one row per
prior of the model, ``noise * (x - centre) / sd``: its sum of squares over
``2 noise^2`` is then the negative log-posterior (white Gaussian noise), so the
least-squares optimum is the MAP estimate. Functions are cached per (model,
free set) so jitted callers never recompile for a second batch of the same shape.
"""

from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.models import ContactModel

__all__ = ["jacobian_fn", "noise_scale", "residual_fn"]


def noise_scale(y: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-trial noise sd (N) from first differences, before any fit.

    ``sqrt(mean(d^2) / 2)`` over differences ``d`` of finite neighbours, the
    largest 2 % left out (movement onsets). Exact for white noise on a smooth
    signal; low by ``sqrt(1 - rho)`` for AR(1) noise, which only weakens the
    priors. 0 where fewer than 2 such pairs exist or they overflow (then the priors drop out).
    """
    pair = mask[:, 1:] & mask[:, :-1]
    with np.errstate(over="ignore", invalid="ignore"):  # overflow: no usable scale (0)
        d2 = np.where(pair, np.diff(np.where(mask, y, 0.0), axis=1), np.nan) ** 2
        out = np.zeros(y.shape[0])
        for i, row in enumerate(d2):
            row = row[np.isfinite(row)]
            if row.size >= 2:
                keep = row[row <= np.quantile(row, 0.98)]
                out[i] = np.sqrt(0.5 * keep.mean())
    return np.where(np.isfinite(out), out, 0.0)


@lru_cache(maxsize=64)
def residual_fn(model: ContactModel, free: tuple[int, ...]):
    """``residual(u_free, data) -> (n + n_priors,)``: prediction minus data (zero where
    masked), then the prior rows."""
    free_idx = jnp.asarray(free)

    def residual(u_free, data):
        y, mask, drive_input, direction, t0, dt, base, noise = data
        u = base.at[free_idx].set(u_free)
        t = t0 + dt * jnp.arange(y.shape[-1], dtype=y.dtype)
        pred = model.predict(u, t, drive_input, direction)
        return jnp.concatenate([jnp.where(mask, pred - y, 0.0),
                                noise * model.prior_residuals(u)])

    return residual


@lru_cache(maxsize=64)
def jacobian_fn(model: ContactModel, free: tuple[int, ...]):
    """Jitted, vmapped ``(u_free, data) -> (r, J^T J)`` for the statistics at the optimum:
    ``r`` the data residuals only, ``J^T J`` with the prior rows."""
    residual = residual_fn(model, free)

    def one(u_free, data):
        def both(u):
            r = residual(u, data)
            return r, r

        jac, r = jax.jacfwd(both, has_aux=True)(u_free)
        return r[: data[0].shape[-1]], jac.T @ jac

    return jax.jit(jax.vmap(one))
