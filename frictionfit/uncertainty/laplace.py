"""Laplace approximation: a Gaussian at the posterior mode in unconstrained coordinates.

The curvature is the Gauss-Newton Hessian of the AR(1)-whitened residuals and of
the model's Normal prior rows, plus the bounds' logistic prior Hessian; one
Gauss-Newton step moves the least-squares optimum to the posterior mode (kept
only if the log-posterior rises). Intervals are the
Gaussian's quantiles in ``u`` mapped through each (monotone) parameter
transform, so physical intervals may be asymmetric.

:func:`profile_disagreement` is the cheap check behind ``uncertainty="auto"``:
along each parameter's Gaussian profile line (``u_mode +/- 2 cov[:, j] /
sd_j``) the Laplace Gaussian predicts a log-posterior drop of exactly 2; the
largest deviation of the true drop from 2 measures non-Gaussianity.
"""

from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.fit import Trials
from frictionfit.fit._noise import ar1_whiten
from frictionfit.fit._numerics import normal_equations, scaled_condition, scaled_pinv
from frictionfit.models import ContactModel
from frictionfit.uncertainty._logpost import OFFSET_PRIOR_SD_N, ROW_AXES, logp_rows

__all__ = ["laplace", "profile_disagreement"]


def _prior_terms(model: ContactModel, u):
    """Gradient and Hessian diagonal of the negative log of the bounds' logistic prior."""
    grads, hess = [], []
    for j, par in enumerate(model.params):
        if par.transform == "identity":
            grads.append(u[j] / OFFSET_PRIOR_SD_N**2)
            hess.append(jnp.full_like(u[j], 1.0 / OFFSET_PRIOR_SD_N**2))
        else:
            s = jax.nn.sigmoid(u[j])
            grads.append(2.0 * s - 1.0)
            hess.append(2.0 * s * (1.0 - s))
    return jnp.stack(grads), jnp.stack(hess)


@lru_cache(maxsize=32)
def _curvature(model: ContactModel):
    """Jitted per-trial Gauss-Newton Hessian and gradient of the negative log-posterior."""

    def whitened(u, trial: Trials, sigma, rho):
        pred = model.predict(u, trial.t, trial.drive_input, trial.direction)
        r = jnp.where(trial.mask, pred - trial.y, 0.0)
        # The model's Normal priors are residual rows of their own (Gauss-Newton too).
        return jnp.concatenate([ar1_whiten(r, trial.mask, sigma, rho),
                                model.prior_residuals(u)])

    def one(u, trial: Trials, sigma, rho):
        _, jtj, jtw = normal_equations(lambda v: whitened(v, trial, sigma, rho), u)
        g_prior, h_prior = _prior_terms(model, u)
        return jtj + jnp.diag(h_prior), jtw + g_prior

    return jax.jit(jax.vmap(one, in_axes=(0, ROW_AXES, 0, 0)))


def laplace(model: ContactModel, data: tuple, u_hat: np.ndarray):
    """Posterior mode, covariance and scaled-Hessian condition number per trial.

    Parameters
    ----------
    model : ContactModel
    data : tuple
        ``(trials, sigma, rho)``: the trials (:func:`~frictionfit.uncertainty._logpost.on_device`,
        same order as ``u_hat``), their noise sd (N) and AR(1) coefficients.
    u_hat : ndarray (n_trials, n_params)
        Least-squares optimum (unconstrained).

    Returns
    -------
    mode : ndarray (n_trials, n_params)
    cov : ndarray (n_trials, n_params, n_params)
        Unconstrained covariance; NaN where the curvature is not finite.
    cond : ndarray (n_trials,)
        Condition number of the unit-diagonal Hessian.
    """
    curv = _curvature(model)
    logp = logp_rows(model)
    idx = np.arange(u_hat.shape[0])
    h, g = (np.asarray(a) for a in curv(jnp.asarray(u_hat), *data))
    step = np.stack([-scaled_pinv(hi) @ gi if np.all(np.isfinite(hi)) and np.all(np.isfinite(gi))
                     else np.zeros_like(gi) for hi, gi in zip(h, g, strict=True)])
    cand = u_hat + step
    better = np.asarray(logp(cand, idx, *data)) > np.asarray(logp(u_hat, idx, *data))
    mode = np.where(better[:, None], cand, u_hat)
    h, _ = (np.asarray(a) for a in curv(jnp.asarray(mode), *data))
    cov = np.full_like(h, np.nan)
    cond = np.full(h.shape[0], np.inf)
    for i, hi in enumerate(h):
        if np.all(np.isfinite(hi)):
            cond[i] = scaled_condition(hi)
            cov[i] = scaled_pinv(hi)
    return mode, cov, cond


def profile_disagreement(model: ContactModel, data: tuple, mode: np.ndarray,
                         cov: np.ndarray) -> np.ndarray:
    """Per trial, max over parameters and sides of ``|drop - 2|`` at 2 sd (see module doc);
    ``data`` as for :func:`laplace`."""
    n, p = mode.shape
    sd = np.sqrt(np.maximum(np.einsum("tii->ti", cov), 1e-300))
    line = cov / sd[:, None, :]  # column j: the Gaussian profile direction of parameter j
    offsets = np.concatenate([2 * line, -2 * line], axis=2).transpose(0, 2, 1)  # (n, 2p, p)
    pts = (mode[:, None, :] + offsets).reshape(-1, p)
    idx = np.repeat(np.arange(n), 2 * p)
    logp = logp_rows(model)
    at_mode = np.asarray(logp(mode, np.arange(n), *data))
    around = np.asarray(logp(np.nan_to_num(pts), idx, *data)).reshape(n, 2 * p)
    dev = np.abs(at_mode[:, None] - around - 2.0)
    return np.where(np.all(np.isfinite(cov), axis=(1, 2)), np.max(dev, axis=1), np.inf)
