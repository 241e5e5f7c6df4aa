"""The one noise model of fit residuals: Gaussian AR(1), its estimate and its likelihood.

Residuals ``r`` (a stroke's samples, or a whole fit's weighted block residuals) follow
``r_t = rho r_{t-1} + e_t``, stationary with marginal sd ``sigma``; a sample whose
predecessor is masked starts a new run (it enters with the marginal variance). The noise
is estimated once, at a fit's optimum, by :func:`ar1_estimate` (its maximum likelihood),
and every use of it evaluates this model at that estimate:

- the law choice: :func:`ar1_deviance`, ``-2`` :func:`ar1_log_likelihood` there (constant
  dropped), behind AIC and BIC;
- a stroke's posterior (Laplace and emcee): :func:`ar1_log_likelihood` plus the log-priors,
  its residual for Gauss-Newton :func:`ar1_whiten`;
- a whole fit's density (its BIC's noise, emcee, the checks of a ridge): the AR(1)
  likelihood in its long-run form, independent residuals of variance
  :func:`long_run_variance`, ``sigma^2 (1 + rho) / (1 - rho)`` (the variance of a mean of
  the noise). Its maximum is the least-squares optimum the fit reports. (The whitened
  likelihood's maximum is another estimate, generalised least squares, which the whole fit
  does not compute.)
- a whole fit's covariance: the sandwich ``A^+ S A^+`` of that optimum (Huber, White), ``A``
  the Gauss-Newton ``J^T J`` and ``S`` the Newey-West long-run covariance of the blocks'
  scores ``J_t r_t`` (:func:`long_run_covariance`, the Bartlett kernel at Andrews' AR(1)
  bandwidth). One noise correlation inflates every parameter alike; the scores' own
  long-run covariance gives each parameter the correlation its own signal sees (a slow
  drift moves a level, barely a slope that changes sign with every stroke).

The functions take NumPy or JAX arrays (the trials along the leading axes, the samples
along the last) and return the same kind.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["RHO_MAX", "ar1_deviance", "ar1_estimate", "ar1_log_likelihood", "ar1_whiten",
           "bartlett_lags", "lag1_rho", "long_run_covariance",
           "long_run_variance"]

#: Bound on |rho| (keeps ``log(1 - rho^2)`` finite).
RHO_MAX = 0.99


def _xp(a):
    return jnp if isinstance(a, jax.Array) else np


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


def ar1_estimate(resid: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Maximum-likelihood marginal sd ``sigma`` (units of ``resid``) and lag-1 coefficient
    ``rho`` per trial of ``resid (n_trials, n_samples)`` (NumPy): ``rho`` the least-squares
    estimate over pairs of masked neighbours, clipped to ``[-RHO_MAX, RHO_MAX]``; ``sigma``
    the likelihood's maximum given ``rho`` (the innovations' mean square over
    ``1 - rho^2``)."""
    resid = np.where(mask, resid, 0.0)
    rho = np.clip(np.nan_to_num(lag1_rho(resid, mask)), -RHO_MAX, RHO_MAX)
    n = np.maximum(mask.sum(axis=1), 1)
    unit = ar1_whiten(resid, mask, np.ones_like(rho), rho)  # innovations over sqrt(1-rho^2)
    var = np.maximum(np.sum(unit**2, axis=1) / n, 1e-300)
    return np.sqrt(var), rho


def ar1_whiten(resid, mask, sigma, rho):
    """The whitened residuals: innovations ``r_t - rho r_{t-1}`` over their sd ``sigma
    sqrt(1 - rho^2)`` (a run's first sample: ``r_t / sigma``); 0 where ``mask`` is False.
    ``-log L`` is half their sum of squares plus :func:`ar1_log_likelihood`'s log terms.
    ``sigma``, ``rho``: one per trial (the leading axes)."""
    xp = _xp(resid)
    sigma, rho = xp.asarray(sigma)[..., None], xp.asarray(rho)[..., None]
    lead = [(0, 0)] * (resid.ndim - 1)
    prev = xp.pad(resid[..., :-1], [*lead, (1, 0)])
    prev_ok = xp.pad(mask[..., :-1], [*lead, (1, 0)])
    innov = xp.where(prev_ok, resid - rho * prev, resid)
    sd = sigma * xp.sqrt(xp.where(prev_ok, 1.0 - rho**2, 1.0))
    return xp.where(mask, innov / sd, 0.0)


def ar1_log_likelihood(resid, mask, sigma, rho):
    """Gaussian AR(1) log-likelihood (with its constant) of ``resid`` where ``mask`` is
    True, per trial; ``sigma`` the marginal sd (units of ``resid``)."""
    xp = _xp(resid)
    w = ar1_whiten(resid, mask, sigma, rho)
    sigma, rho = xp.asarray(sigma)[..., None], xp.asarray(rho)[..., None]
    lead = [(0, 0)] * (resid.ndim - 1)
    prev_ok = xp.pad(mask[..., :-1], [*lead, (1, 0)])
    log_sd = xp.log(sigma) + 0.5 * xp.log(xp.where(prev_ok, 1.0 - rho**2, 1.0))
    return -xp.sum(xp.where(mask, 0.5 * w**2 + log_sd + 0.5 * np.log(2 * np.pi), 0.0),
                   axis=-1)


def ar1_deviance(resid, mask) -> np.ndarray:
    """``-2 log L`` per trial of ``resid (n_trials, n_samples)`` (zero where ``mask`` is
    False) at the noise's estimate (:func:`ar1_estimate`: the likelihood profiled over
    ``sigma`` and ``rho``), its constant ``n (1 + log 2 pi)`` dropped:
    ``n log(S / n) - g log(1 - rho^2)``, ``S`` the innovations' sum of squares (a run's
    first sample scaled by ``sqrt(1 - rho^2)``), ``g`` the number of runs."""
    resid = np.where(mask, resid, 0.0)
    sigma, rho = ar1_estimate(resid, mask)
    n = mask.sum(axis=1).astype(np.float64)
    return -2.0 * ar1_log_likelihood(resid, mask, sigma, rho) - n * (1.0 + np.log(2 * np.pi))


#: The largest lag-one correlation the long-run variance takes: beyond it the residual is the
#: model's own structured misfit rather than AR(1) noise, and ``(1 + rho) / (1 - rho)`` (39 at
#: the cap, 199 at 0.99) would bury every parameter's standard error in it.
RHO_CAP = 0.95


def long_run_variance(sigma, rho):
    """``sigma^2 (1 + r) / (1 - r)`` with ``r = min(rho, RHO_CAP)``: the variance per residual
    of the AR(1) likelihood's long-run form (units of ``sigma`` squared)."""
    r = np.minimum(rho, RHO_CAP)
    return sigma**2 * (1.0 + r) / (1.0 - r)


def bartlett_lags(rho, n) -> np.ndarray:
    """Lags of the Bartlett kernel per item: Andrews' (1991) AR(1) plug-in bandwidth
    ``1.1447 (alpha n)^(1/3)``, ``alpha = 4 r^2 / ((1 - r)^2 (1 + r)^2)``, ``r`` the lag-one
    coefficient ``rho`` within ``+-RHO_CAP``, ``n`` the samples; at most ``n - 1``."""
    r = np.clip(np.asarray(rho, dtype=np.float64), -RHO_CAP, RHO_CAP)
    alpha = 4.0 * r**2 / ((1.0 - r) ** 2 * (1.0 + r) ** 2)
    lags = np.ceil(1.1447 * (alpha * np.asarray(n)) ** (1.0 / 3.0))
    return np.minimum(lags, np.maximum(np.asarray(n) - 1, 0)).astype(np.int64)


def long_run_covariance(scores: np.ndarray, mask: np.ndarray, rho) -> np.ndarray:
    """Newey-West long-run covariance ``(n_items, q, q)`` of ``scores (n_items, N, q)``
    summed over the samples where ``mask``: ``sum_(t, t') w(t - t') s_t s_t'^T`` with
    Bartlett weights ``w(l) = max(0, 1 - |l| / (L + 1))``, ``L`` per item from
    :func:`bartlett_lags` (``rho``: the residuals' lag-one coefficient). Computed exactly as
    ``sum_j W_j W_j^T / (L + 1)`` over the sums ``W_j`` of every window of ``L + 1``
    consecutive scores of the zero-padded series: positive semidefinite, ``O(N q^2)``. Units
    of the scores squared."""
    s = np.where(mask[..., None], scores, 0.0)
    lags = bartlett_lags(rho, mask.sum(axis=1))
    out = np.empty((s.shape[0], s.shape[2], s.shape[2]))
    for i, lag in enumerate(lags):
        padded = np.pad(s[i], ((lag + 1, lag), (0, 0)))
        cum = np.cumsum(padded, axis=0)
        windows = cum[lag + 1:] - cum[: -lag - 1]
        out[i] = windows.T @ windows / (lag + 1.0)
    return out
