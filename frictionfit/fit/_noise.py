"""The AR(1) noise model of residuals: its lag-1 coefficient and its likelihood.

Residuals ``r`` (N) follow ``r_t = rho r_{t-1} + e_t``; a sample whose predecessor
is missing starts a new stationary run (it enters with the marginal variance).
The fit profiles ``rho`` and the innovation variance out of the likelihood
(:func:`ar1_deviance`, NumPy); the posterior holds both at their least-squares
estimates (:func:`noise_estimate`) and evaluates :func:`ar1_log_likelihood` (JAX).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

__all__ = ["RHO_MAX", "RHO_POSTERIOR", "ar1_deviance", "ar1_innovations",
           "ar1_log_likelihood", "lag1_rho", "noise_estimate"]

#: Bound on |rho| in the fit's deviance (keeps ``log(1 - rho^2)`` finite).
RHO_MAX = 0.99
#: Range of rho held fixed in the posterior (anticorrelated noise is not expected).
RHO_POSTERIOR = (0.0, 0.95)


def lag1_rho(resid: np.ndarray, mask: np.ndarray, over_pairs: bool = True) -> np.ndarray:
    """Unclipped lag-1 coefficient per trial of ``resid (n_trials, n_samples)``.

    Cross-products over pairs of masked neighbours divided by the sum of squares of
    the pairs' earlier samples (least squares, ``over_pairs``) or of every masked
    sample (the sample autocorrelation).
    """
    r = np.where(mask, resid, 0.0)
    pair = mask[:, 1:] & mask[:, :-1]
    cross = np.sum(np.where(pair, r[:, 1:] * r[:, :-1], 0.0), axis=1)
    ss = (np.sum(np.where(pair, r[:, :-1], 0.0) ** 2, axis=1) if over_pairs
          else np.sum(r**2, axis=1))
    return cross / np.maximum(ss, 1e-300)


def ar1_deviance(resid, mask) -> np.ndarray:
    """``-2 log L`` (constant dropped) of residuals under Gaussian AR(1) noise, per trial.

    ``resid`` (n_trials, n_samples), zero where ``mask`` is False. The coefficient
    is the lag-1 least-squares estimate over pairs of finite neighbours, clipped to
    ``[-RHO_MAX, RHO_MAX]``; each contiguous run of finite samples starts a new
    stationary segment (a gap of missing samples breaks the recurrence).
    """
    resid = np.where(mask, resid, 0.0)
    n = mask.sum(axis=1).astype(np.float64)
    pair = mask[:, 1:] & mask[:, :-1]
    prev, cur = resid[:, :-1] * pair, resid[:, 1:] * pair
    rho = np.clip(np.nan_to_num(lag1_rho(resid, mask)), -RHO_MAX, RHO_MAX)
    starts = mask.copy()
    starts[:, 1:] &= ~mask[:, :-1]  # first finite sample of each run
    lead = (1 - rho**2) * np.sum(np.where(starts, resid, 0.0) ** 2, axis=1)
    sse = lead + np.sum((cur - rho[:, None] * prev) ** 2, axis=1)
    g = starts.sum(axis=1)
    return (n * np.log(np.maximum(sse / np.maximum(n, 1.0), 1e-300))
            - g * np.log1p(-rho**2))


def noise_estimate(resid: np.ndarray, mask: np.ndarray, n_params: int):
    """Marginal noise sd (N) and lag-1 autocorrelation (clipped to RHO_POSTERIOR) per
    trial, from least-squares residuals."""
    n = mask.sum(axis=1)
    ss = np.sum(np.where(mask, resid, 0.0) ** 2, axis=1)
    sigma = np.sqrt(ss / np.maximum(n - n_params, 1))
    return sigma, np.clip(lag1_rho(resid, mask, over_pairs=False), *RHO_POSTERIOR)


def ar1_innovations(resid, mask, rho):
    """Innovations ``r_t - rho r_{t-1}`` of one trial's ``resid (n_samples,)`` (JAX) and
    their variance in units of the marginal one (``1 - rho^2``, or 1 after a gap)."""
    prev_ok = jnp.concatenate([jnp.zeros(1, dtype=bool), mask[:-1]])
    prev = jnp.concatenate([jnp.zeros(1, dtype=resid.dtype), resid[:-1]])
    innov = jnp.where(prev_ok, resid - rho * prev, resid)
    return innov, jnp.where(prev_ok, 1.0 - rho**2, 1.0)


def ar1_log_likelihood(resid, mask, sigma, rho):
    """AR(1) Gaussian log-likelihood of residuals ``resid`` (N) where ``mask`` is True;
    ``sigma`` the marginal sd (N)."""
    innov, factor = ar1_innovations(resid, mask, rho)
    var = sigma**2 * factor
    terms = jnp.where(mask, innov**2 / var + jnp.log(var), 0.0)
    return -0.5 * jnp.sum(terms)
