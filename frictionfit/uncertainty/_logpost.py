"""The per-trial log-posterior of a contact model, in unconstrained coordinates (JAX).

Likelihood: the one AR(1) Gaussian likelihood of :mod:`frictionfit.fit._noise`
(residuals of rubbing signals are autocorrelated), ``r_t = rho r_{t-1} + e_t``,
marginal sd ``sigma``. ``sigma`` (N) and ``rho`` are estimated once per trial from the
least-squares residuals (:func:`~frictionfit.fit._noise.ar1_estimate`; thousands of
samples pin them, so plugging them in barely narrows the posterior) and held fixed
while sampling. A sample whose predecessor is missing (NaN) enters with its marginal
variance.

Priors (weakly informative, from each parameter's physical bounds): a bounded
parameter's unconstrained ``u`` has a standard logistic density, i.e. the
physical value is uniform over its bounds (``logit``) or log-uniform over them
(``loglogit``: stiffness, friction levels, lengths and times span decades).
Offsets (``identity``) get a Normal(0, ``OFFSET_PRIOR_SD_N``) prior. The model's
own priors (:meth:`~frictionfit.models.ContactModel.prior_residuals`, e.g. the
movement duration's) multiply in: the same density the fit's MAP maximises. A NaN or
infinite log-posterior is mapped to ``-inf`` (the sampler rejects the move).

emcee samples the same posterior in *sampling coordinates* (:func:`to_sampling`):
the log of a ``loglogit`` parameter, the value of a ``logit`` one, an offset as
is. There the priors above are flat on the bounds (the logistic density in ``u``
is exactly the Jacobian of the logistic map), so the posterior density is the
likelihood times a box, and the map back to ``u`` is exact. Why: the contact
model's weakly identified directions are straight lines in log units (the onset
of a trial fixes ``k / ramp**2`` and ``slip_length * ramp**2``: posterior
correlations 0.99), but the logistic map of ``u`` bends them into thin curved
ridges, on which every emcee move mixes slowly (see ``_ensemble``).
"""

from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.fit import Trials
from frictionfit.fit._noise import ar1_log_likelihood
from frictionfit.models import ContactModel

__all__ = ["OFFSET_PRIOR_SD_N", "ROW_AXES", "from_sampling", "log_logistic", "log_prior",
           "logp_rows", "on_device", "residuals", "sampling_bounds", "to_sampling"]

#: Prior sd of a channel offset, N (sensor offsets are at most tens of N).
OFFSET_PRIOR_SD_N = 100.0


def log_logistic(u):
    """Log density of the standard logistic at ``u``: the log Jacobian of the logistic map
    from an unconstrained coordinate to its bounded value (a flat density there); NumPy for
    a NumPy ``u``."""
    if isinstance(u, np.ndarray):
        return -np.logaddexp(0.0, u) - np.logaddexp(0.0, -u)
    return -jax.nn.softplus(u) - jax.nn.softplus(-u)


def log_prior(model: ContactModel, u):
    """Log prior density of unconstrained ``u[..., n_params]`` (up to a constant)."""
    total = jnp.zeros(u.shape[:-1], dtype=u.dtype)
    for j, par in enumerate(model.params):
        uj = u[..., j]
        if par.transform == "identity":
            total = total - 0.5 * (uj / OFFSET_PRIOR_SD_N) ** 2
        else:  # standard logistic: uniform on the (log-)span of the bounds
            total = total + log_logistic(uj)
    return total - 0.5 * jnp.sum(model.prior_residuals(u) ** 2, axis=-1)


def sampling_bounds(model: ContactModel) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bound of each sampling coordinate (+/-inf for offsets)."""
    lo = np.array([-np.inf if p.transform == "identity" else p.span[0]
                   for p in model.params])
    hi = np.array([np.inf if p.transform == "identity" else p.span[1]
                   for p in model.params])
    return lo, hi


def to_sampling(model: ContactModel, u: np.ndarray) -> np.ndarray:
    """Sampling coordinates (log value, value, or offset) of unconstrained ``u[..., p]``."""
    u = np.asarray(u, dtype=np.float64)
    return np.stack([p.to_sampling(u[..., j]) for j, p in enumerate(model.params)], axis=-1)


def from_sampling(model: ContactModel, x, xp=np):
    """Unconstrained ``u`` of sampling coordinates ``x[..., p]`` (NumPy or ``xp=jnp``)."""
    lo, hi = sampling_bounds(model)
    bounded = np.isfinite(lo)
    lo0, span = np.where(bounded, lo, 0.0), np.where(bounded, hi - lo, 1.0)
    frac = xp.clip((x - lo0) / span, 1e-300, 1.0)
    return xp.where(bounded, xp.log(frac) - xp.log1p(-xp.minimum(frac, 1.0 - 1e-16)), x)


def log_prior_sampling(model: ContactModel, x):
    """Log prior in sampling coordinates: flat inside the bounds (times the model's
    Normal priors), -inf outside."""
    lo, hi = sampling_bounds(model)
    inside = jnp.all((x > lo) & (x < hi), axis=-1)
    off = np.array([p.transform == "identity" for p in model.params])
    gauss = -0.5 * jnp.sum(jnp.where(off, x / OFFSET_PRIOR_SD_N, 0.0) ** 2, axis=-1)
    gauss = gauss - 0.5 * jnp.sum(model.prior_residuals(x, sampling=True) ** 2, axis=-1)
    return jnp.where(inside, gauss, -jnp.inf)


#: ``jax.vmap`` axes of :class:`~frictionfit.fit.Trials` (``drive="events"``), one trial a row.
ROW_AXES = Trials(t=None, y=0, drive_input=0, direction=0, mask=0)


def on_device(trials: Trials) -> Trials:
    """``trials`` (``drive="events"``) as JAX arrays, without ids: moved to the device once,
    not at every call of a jitted function."""
    return jax.tree_util.tree_map(jnp.asarray, trials.arrays_only())


def _one_logp(model: ContactModel, u, t, y, mask, drive_input, direction, sigma, rho,
              sampling=False):
    if sampling:  # u holds sampling coordinates
        prior = log_prior_sampling(model, u)
        u = from_sampling(model, u, jnp)
    else:
        prior = log_prior(model, u)
    pred = model.predict(u, t, drive_input, direction)
    resid = jnp.where(mask, pred - y, 0.0)
    lp = ar1_log_likelihood(resid, mask, sigma, rho) + prior
    return jnp.where(jnp.isfinite(lp), lp, -jnp.inf)


@lru_cache(maxsize=32)
def logp_rows(model: ContactModel, sampling: bool = False):
    """Jitted ``f(U (R, p), idx (R,), trials, sigma, rho) -> log-posterior (R,)``.

    Row ``r`` is walker ``U[r]`` of trial ``idx[r]`` of ``trials`` (:func:`on_device`),
    whose noise sd (N) and AR(1) coefficient are ``sigma`` and ``rho`` (per trial): walkers
    of many trials go through one vmapped call. ``sampling=True``: ``U`` in sampling
    coordinates (:func:`to_sampling`), the density of the same posterior there.
    """

    def rows(U, idx, trials: Trials, sigma, rho):
        t_out, t_back = trials.drive_input

        def one(u, i):
            return _one_logp(model, u, trials.t, trials.y[i], trials.mask[i],
                             (t_out[i], t_back[i]), trials.direction[i], sigma[i], rho[i],
                             sampling)

        return jax.vmap(one)(U, idx)

    return jax.jit(rows)


@lru_cache(maxsize=32)
def residuals(model: ContactModel):
    """Jitted ``f(u (T, p), trials) -> pred - y`` (N, 0 where not used), trial by trial."""

    def one(u, trial: Trials):
        pred = model.predict(u, trial.t, trial.drive_input, trial.direction)
        return jnp.where(trial.mask, pred - trial.y, 0.0)

    return jax.jit(jax.vmap(one, in_axes=(0, ROW_AXES)))
