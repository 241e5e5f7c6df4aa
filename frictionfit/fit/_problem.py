"""The least-squares problem of one trial: masked residual and its Jacobian.

Per-trial data is a :class:`Problem`: the trial's arrays of a
:class:`~frictionfit.fit.trials.Trials` (with its own first sample time and
interval, so the solver's pools can take any trial's row), ``base``, the full
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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.fit.trials import Trials
from frictionfit.models import ContactModel

__all__ = ["Problem", "jacobian_fn", "noise_scale", "residual_fn"]


class Problem(eqx.Module):
    """The least-squares data of each trial, one row per trial (the solver's pools take rows).

    ``y`` force (N, 0 where not used), ``mask`` the used samples, ``drive_input`` as in
    :class:`~frictionfit.fit.trials.Trials`, ``direction`` +1/-1, ``t0`` and ``dt`` the
    first sample time and the interval (s), ``base`` unconstrained parameters (the held
    ones' values), ``noise`` the noise sd (N).
    """

    y: np.ndarray
    mask: np.ndarray
    drive_input: tuple | np.ndarray
    direction: np.ndarray
    t0: np.ndarray
    dt: np.ndarray
    base: np.ndarray
    noise: np.ndarray

    @classmethod
    def of(cls, trials: Trials, base: np.ndarray, noise: np.ndarray | None = None) -> Problem:
        """The problem of fitting ``trials`` from ``base``; ``noise`` (N) by default
        :meth:`noise_of` them."""
        n = trials.n_trials
        return cls(trials.filled, trials.mask, trials.drive_input, trials.direction,
                   np.full(n, trials.t[0]), np.full(n, trials.dt), base,
                   cls.noise_of(trials) if noise is None else noise)

    @staticmethod
    def noise_of(trials: Trials) -> np.ndarray:
        """Per-trial noise sd (N) of the samples ``trials`` use (:func:`noise_scale`)."""
        return noise_scale(trials.filled, trials.mask)


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

    def residual(u_free, data: Problem):
        u = data.base.at[free_idx].set(u_free)
        t = data.t0 + data.dt * jnp.arange(data.y.shape[-1], dtype=data.y.dtype)
        pred = model.predict(u, t, data.drive_input, data.direction)
        return jnp.concatenate([jnp.where(data.mask, pred - data.y, 0.0),
                                data.noise * model.prior_residuals(u)])

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
        return r[: data.y.shape[-1]], jac.T @ jac

    return jax.jit(jax.vmap(one))
