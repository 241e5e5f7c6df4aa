"""Posterior uncertainties of fitted contact-model parameters: Laplace and emcee.

:func:`sample_posterior` takes a :class:`~frictionfit.fit.FitResult` and the
data it was fitted to and returns a :class:`Posterior` per trial, by one of

- ``"laplace"``: a Gaussian at the posterior mode (fast; one Jacobian per trial);
- ``"emcee"``: one emcee ensemble (``vectorize=True``) holding the walkers of
  every running trial, each moved only by its own trial's proposal, so one batched
  JAX call per step evaluates them all; in log coordinates with an adaptive
  independence proposal (pilot-fitted; see ``_ensemble``), each trial run until its
  chain is >= 50 integrated autocorrelation times long and its walkers agree (R-hat);
- ``"auto"`` (default): Laplace, except emcee for the trials where Laplace is
  not to be trusted: the fit did not end ``CONVERGED`` (e.g. ill-conditioned),
  a parameter is flagged "at bound" or "singular" by the fit, the Hessian's
  condition number exceeds :data:`AUTO_MAX_COND`, or the log-posterior along a
  parameter's Gaussian profile line, 2 sd out, differs from the Gaussian's drop
  of 2 by more than :data:`AUTO_MAX_PROFILE_DEV` (see
  :func:`~frictionfit.uncertainty.laplace.profile_disagreement`). The fit's
  "stderr > value" flag alone does not send a trial to emcee: bounded parameters
  are Gaussian in their log/logit coordinate, where a wide posterior is fine for
  Laplace as long as the profile check passes.

The log-posterior (AR(1) Gaussian likelihood, priors from the parameter bounds)
is described in :mod:`frictionfit.uncertainty._logpost`.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import jax.numpy as jnp
import numpy as np
from emcee.backends import HDFBackend

from frictionfit._optional import require
from frictionfit._system import available_cores
from frictionfit.errors import FitError, Status
from frictionfit.fit import FitResult, MeasurementFit, Trials
from frictionfit.fit._noise import ar1_estimate
from frictionfit.fit._numerics import fd_slope, pad_rows
from frictionfit.fit._stats import VANISHING
from frictionfit.models import ContactModel, get_model
from frictionfit.uncertainty._ensemble import ChainResult, run_lockstep
from frictionfit.uncertainty._logpost import (
    from_sampling,
    logp_rows,
    on_device,
    residuals,
    to_sampling,
)
from frictionfit.uncertainty.laplace import laplace, profile_disagreement
from frictionfit.uncertainty.posterior import QUANTILES, Posterior

__all__ = ["AUTO_MAX_COND", "AUTO_MAX_PROFILE_DEV", "METHODS", "ROW_STATS", "SamplerSettings",
           "TrialGroup", "auto_reason", "blank_rows", "emcee_summary", "nan_summary", "put_summary",
           "sample_posterior", "store_chain"]

METHODS = ("laplace", "emcee", "auto")
#: ``auto``: condition number of the unit-diagonal Hessian above which emcee is used.
AUTO_MAX_COND = 1e8
#: ``auto``: largest tolerated |log-posterior drop - 2| at 2 sd on a profile line.
AUTO_MAX_PROFILE_DEV = 1.0
_SKIP = (Status.NONFINITE, Status.INSUFFICIENT_DATA)


@dataclass(frozen=True)
class SamplerSettings:
    """How every trial's posterior is computed (see :func:`sample_posterior`)."""

    method: str
    noise: str
    nwalkers: int | None
    max_steps: int
    check_every: int
    min_tau_multiple: float
    seed: int
    chains_path: object
    pilot_steps: int


@dataclass(frozen=True, eq=False)
class TrialGroup:
    """The trials of a batch fitted with one model: their rows in the batch and the trials."""

    model: ContactModel
    rows: np.ndarray
    trials: Trials


@dataclass(frozen=True, eq=False)
class _Noise:
    """Per trial of a group: noise sd (N) and AR(1) coefficient."""

    sigma: np.ndarray
    rho: np.ndarray


def _directions(model, trials: Trials, u) -> np.ndarray:
    """The channel sign (+1/-1) under which ``u`` fits each trial best."""
    res = residuals(model)
    chi2 = [np.sum(np.asarray(res(u, on_device(replace(
        trials, direction=np.full(len(u), s))))) ** 2, axis=1) for s in (1.0, -1.0)]
    return np.where(chi2[0] <= chi2[1], 1.0, -1.0)


def auto_reason(fit: FitResult, i: int, cond: float, dev: float) -> str:
    """Why trial ``i`` needs emcee under the ``auto`` policy ("" when Laplace is fine)."""
    if fit.status[i] != Status.CONVERGED:
        return f"fit status {Status(int(fit.status[i])).name.lower()}"
    bad = {k: v for k, v in fit.flags[i].items() if v in VANISHING}
    if bad:
        return "flagged: " + ", ".join(f"{k} {v}" for k, v in bad.items())
    if not cond <= AUTO_MAX_COND:
        return f"ill-conditioned (cond {cond:.2g})"
    if not dev <= AUTO_MAX_PROFILE_DEV:
        return f"non-Gaussian profile (|drop - 2| = {dev:.2g})"
    return ""


def _laplace_summary(model, mode, cov):
    """Quantiles and sd (physical) of one trial's Laplace Gaussian."""
    from scipy.stats import norm

    sd_u = np.sqrt(np.maximum(np.diag(cov), 0.0))
    quant, sd = {}, {}
    for j, par in enumerate(model.params):
        quant[par.name] = np.array([float(par.to_physical(np.float64(mode[j] + norm.ppf(q)
                                                                     * sd_u[j])))
                                    for q in QUANTILES.values()])
        slope = float(fd_slope(par.to_physical, np.float64(mode[j])))
        sd[par.name] = abs(slope) * sd_u[j]
    return quant, sd


#: A row's statistics per parameter besides its quantiles: posterior sd (physical unit),
#: and emcee's integrated autocorrelation time (steps), effective sample size and R-hat.
ROW_STATS = ("sd", "tau", "ess", "rhat")


def blank_rows(n: int) -> dict:
    """The fields of a :class:`Posterior` of ``n`` rows, none filled yet (method "none")."""
    return dict(method=["none"] * n, reason=[""] * n, converged=np.zeros(n, dtype=bool),
                quantiles=[None] * n, **{k: [None] * n for k in ROW_STATS},
                acceptance=np.full(n, np.nan), chains=[None] * n)


def nan_summary(names) -> dict:
    """A row's quantiles and :data:`ROW_STATS`, NaN for every parameter in ``names``."""
    return ({"quantiles": {p: np.full(len(QUANTILES), np.nan) for p in names}}
            | {k: dict.fromkeys(names, np.nan) for k in ROW_STATS})


def emcee_summary(model, chain: ChainResult) -> dict:
    """A row's quantiles and :data:`ROW_STATS` from its chain (unconstrained samples)."""
    flat = chain.samples.reshape(-1, chain.samples.shape[-1])
    stats = {"tau": chain.tau, "ess": chain.ess(),
             "rhat": np.full(len(model.params), np.nan) if chain.rhat is None else chain.rhat}
    out = nan_summary(model.param_names)
    for j, par in enumerate(model.params):
        phys = np.asarray(par.to_physical(flat[:, j]))
        out["quantiles"][par.name] = np.quantile(phys, list(QUANTILES.values()))
        out["sd"][par.name] = float(np.std(phys, ddof=1))
        for key, values in stats.items():
            out[key][par.name] = float(values[j])
    return out


def put_summary(out: dict, i: int, summary: dict) -> None:
    """Row ``i``'s summary (:func:`emcee_summary`, :func:`nan_summary`) into ``out``."""
    for key, value in summary.items():
        out[key][i] = value


#: Rows of one batched log-posterior call (larger batches outgrow the CPU's cache).
EVAL_CHUNK = 256


def _evaluator(model, data: tuple, pool: ThreadPoolExecutor, workers: int,
               max_rows: int, sampling: bool = False):
    """``evaluate(U, idx)`` for the sampler (``data``: :func:`_trial_data`): the rows cut
    into chunks of at most
    :data:`EVAL_CHUNK` (padded to a power of two, so few shapes compile), evaluated
    on ``workers`` threads of ``pool`` (a JAX call releases the GIL).

    Every chunk shape up to ``max_rows`` rows is compiled here, before sampling: the
    rows shrink as trials converge, and each new shape would otherwise stall the
    sampler for a compilation in the middle of a run.
    """
    f = logp_rows(model, sampling)

    def chunk(U: np.ndarray, idx: np.ndarray) -> np.ndarray:
        n = U.shape[0]
        rows = pad_rows(np.arange(n), max(32, 1 << (n - 1).bit_length()))
        return np.asarray(f(U[rows], idx[rows], *data))[:n]

    def evaluate(U: np.ndarray, idx: np.ndarray) -> np.ndarray:
        parts = max(-(-U.shape[0] // EVAL_CHUNK), min(workers, U.shape[0] // 64))
        if parts <= 1:
            return chunk(U, idx)
        return np.concatenate(list(pool.map(chunk, np.array_split(U, parts),
                                            np.array_split(idx, parts))))

    sizes = [32 << k for k in range(EVAL_CHUNK.bit_length()) if 32 << k <= EVAL_CHUNK
             and 32 << k < 2 * max_rows]
    list(pool.map(lambda n: chunk(np.zeros((n, model.n_params)), np.zeros(n, dtype=int)),
                  sizes))
    return evaluate


def sample_posterior(
    fit: FitResult, y, t=None, drive_input=None, *, method: str = "auto", noise: str = "ar1",
    nwalkers: int | None = None, max_steps: int = 3000, check_every: int = 25,
    min_tau_multiple: float = 50.0, seed: int = 0, chains_path=None, pilot_steps: int = 30,
) -> Posterior:
    """Posterior of every trial's parameters, by Laplace and/or emcee.

    Parameters
    ----------
    fit : FitResult
        The least-squares fits (``drive="events"``) of the trials in ``y``.
    y : array (n_trials, n_samples), or Trials
        The force (N) that was fitted; NaN marks missing samples. Or the
        :class:`~frictionfit.fit.Trials` that were fitted (then ``t`` and ``drive_input``
        are not given). Either way the posterior uses exactly the samples the fit used,
        and the fit's channel signs (``fit.direction``).
    t : array (n_samples,)
        Sample times, s.
    drive_input : tuple
        ``(t_out, t_back)`` command times, s (scalars or per trial).
    method : {"auto", "laplace", "emcee"}
        See the module docstring for the ``auto`` policy.
    noise : {"ar1", "white"}
        Likelihood: AR(1) residuals (rho estimated per trial) or white.
    nwalkers : int, optional
        Walkers per trial; default ``n_params + 1``. Each walker is a chain of its own
        (no move mixes them), so more walkers cost more per step without shortening the
        chain that R-hat over the walkers asks of each.
    max_steps, check_every, min_tau_multiple
        emcee step cap (of the kept chain), steps between tau checks, required chain
        length in tau.
    seed : int
        Seed of the walkers' start and moves: one random stream for the whole batch, so
        a trial's draws depend on which trials share its batch (deterministic given both).
    chains_path : path, optional
        Save emcee chains to this HDF5 file (one group ``trial_<i>`` per trial), in
        sampling coordinates (log of log-scaled parameters: see ``_logpost``).
    pilot_steps : int
        Steps of each of the three adaptation stages before the kept chain.

    Returns
    -------
    Posterior
        One entry per trial; trials whose fit is NONFINITE or INSUFFICIENT_DATA
        get method ``"none"``, NaN values and ``converged=False``.

    Examples
    --------
    >>> from frictionfit.simulation.trials import simulate_trials
    >>> from frictionfit.fit import fit_trials
    >>> ts = simulate_trials("elastic_plastic", 2, seed=0)
    >>> res = fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model="elastic_plastic")
    >>> post = sample_posterior(res, ts.y, ts.t, (ts.t_out, ts.t_back), method="laplace")
    >>> post.method
    ['laplace', 'laplace']
    """
    how = _settings(fit, method, noise, nwalkers, max_steps, check_every, min_tau_multiple,
                    seed, chains_path, pilot_steps)
    start = time.perf_counter()
    trials = _inputs(fit, y, t, drive_input)
    n = trials.n_trials
    out = blank_rows(n)
    for name in dict.fromkeys(fit.model):
        model = get_model(name, stroke_mm=getattr(fit, "stroke_mm", 1.0),
                          priors=getattr(fit, "priors", None))
        rows = _sampled_rows(fit, model, out)
        if rows.size:
            _sample_group(fit, TrialGroup(model, rows, trials.take(rows)), how, out)
    return Posterior(model=list(fit.model), wall_s=time.perf_counter() - start, **out)


def _settings(fit, method, noise, nwalkers, max_steps, check_every, min_tau_multiple, seed,
              chains_path, pilot_steps) -> SamplerSettings:
    """The sampler's settings, checked against the fit."""
    if isinstance(fit, MeasurementFit):
        raise FitError("sample_posterior takes per-stroke fits (fit_trials); a whole fit "
                       "samples its own: fit.posterior(method=...)")
    if getattr(fit, "drive", "events") != "events":
        raise FitError(f"sample_posterior needs a fit with drive='events', not {fit.drive!r}")
    if method not in METHODS:
        raise FitError(f"unknown uncertainty method {method!r}; choose from {METHODS}")
    if noise not in ("ar1", "white"):
        raise FitError(f"unknown noise model {noise!r}; choose 'ar1' or 'white'")
    return SamplerSettings(method, noise, nwalkers, max_steps, check_every, min_tau_multiple,
                           seed, chains_path, pilot_steps)


def _inputs(fit: FitResult, y, t, drive_input) -> Trials:
    """The fitted trials, checked against the fit, with the fit's channel signs where it has
    them (a placeholder +1 otherwise: :func:`_noise` derives them)."""
    if isinstance(y, Trials):
        trials = y
    else:
        y = np.atleast_2d(np.asarray(y, dtype=np.float64))
        t = np.asarray(t, dtype=np.float64)
        if y.shape[0] != fit.n_trials or y.shape[1] != t.size:
            raise FitError(f"y is {y.shape} but the fit has {fit.n_trials} trials and t has "
                           f"{t.size} samples")
        trials = Trials.from_arrays(y, t, drive_input, direction=np.ones(y.shape[0]))
    if trials.n_trials != fit.n_trials or trials.drive != "events":
        raise FitError(f"{trials.n_trials} trials with drive={trials.drive!r}, but the fit has "
                       f"{fit.n_trials} trials with drive='events'")
    if fit.direction is not None:
        trials = replace(trials, direction=np.asarray(fit.direction, dtype=np.float64))
    return trials


def _sampled_rows(fit: FitResult, model: ContactModel, out: dict) -> np.ndarray:
    """The rows fitted with ``model`` that can be sampled; the others get NaN summaries
    and the reason in ``out``."""
    rows = np.array([i for i in range(fit.n_trials) if fit.model[i] == model.name])
    for i in rows:
        put_summary(out, i, nan_summary(model.param_names))
    held = [i for i in rows if {"fixed", "tied"} & set(fit.flags[i].values())]
    ok = np.array([fit.status[i] not in _SKIP and np.all(np.isfinite(fit.u[i]))
                   and i not in held for i in rows], dtype=bool)
    for i in rows[~ok]:
        out["reason"][i] = ("skipped: fixed or tied parameters are not sampled yet"
                            if i in held else
                            f"skipped: fit status {Status(int(fit.status[i])).name.lower()}")
    return rows[ok]


def _trial_data(trials: Trials, noise: _Noise, sel=slice(None)) -> tuple:
    """``(trials, sigma, rho)`` of the trials ``sel``, on the device, as the log-posterior
    takes them."""
    return (on_device(trials.take(sel)), jnp.asarray(noise.sigma[sel]),
            jnp.asarray(noise.rho[sel]))


def _with_directions(fit: FitResult, group: TrialGroup, u_hat: np.ndarray) -> Trials:
    """The group's trials with the fit's channel signs; derived from ``u_hat`` only for a
    fit that does not carry them."""
    if fit.direction is not None:
        return group.trials
    return replace(group.trials, direction=_directions(group.model, group.trials, u_hat))


def _noise(model: ContactModel, trials: Trials, u_hat: np.ndarray, white: bool) -> _Noise:
    """Noise sd (N) and AR(1) coefficient of ``trials`` at the fit ``u_hat``."""
    resid = np.asarray(residuals(model)(u_hat, on_device(trials)))
    if white:  # the likelihood's estimate with rho held at 0
        n = np.maximum(trials.mask.sum(axis=1), 1)
        sigma = np.sqrt(np.sum(np.where(trials.mask, resid, 0.0) ** 2, axis=1) / n)
        return _Noise(sigma, np.zeros_like(sigma))
    return _Noise(*ar1_estimate(resid, trials.mask))


def _sample_group(fit: FitResult, group: TrialGroup, how: SamplerSettings, out: dict) -> None:
    """Laplace for every trial of one model, then emcee where ``how.method`` asks for it."""
    model, rows = group.model, group.rows
    u_hat = np.stack([fit.u[i] for i in rows])
    trials = _with_directions(fit, group, u_hat)
    noise = _noise(model, trials, u_hat, how.noise == "white")
    data = _trial_data(trials, noise)
    mode, cov, cond = laplace(model, data, u_hat)
    finite = np.all(np.isfinite(cov), axis=(1, 2))
    if how.method == "auto":
        dev = profile_disagreement(model, data, mode, cov)
        reasons = [auto_reason(fit, i, cond[k], dev[k]) for k, i in enumerate(rows)]
    else:
        reasons = [how.method] * rows.size
    use_emcee = np.array([how.method == "emcee" or (how.method == "auto" and bool(r))
                          for r in reasons])
    for k, i in enumerate(rows):
        out["reason"][i] = reasons[k] or "laplace ok"
        if not use_emcee[k]:
            _store_laplace(fit, model, i, mode[k], cov[k], bool(finite[k]), out)
    sel = np.flatnonzero(use_emcee)
    if sel.size:
        _sample_emcee(model, rows[sel], _trial_data(trials, noise, sel), mode[sel], cov[sel], how,
                      out)


def _store_laplace(fit: FitResult, model, i: int, mode, cov, finite: bool, out: dict) -> None:
    """Trial ``i``'s Laplace summary (or why there is none) into ``out``."""
    out["method"][i] = "laplace"
    # A Gaussian at a point the fit did not converge to is no posterior summary.
    fit_ok = int(fit.status[i]) == Status.CONVERGED
    out["converged"][i] = finite and fit_ok
    if finite:
        out["quantiles"][i], out["sd"][i] = _laplace_summary(model, mode, cov)
    else:
        out["reason"][i] = "laplace covariance not finite; use emcee"
    if not fit_ok:
        out["reason"][i] = (f"laplace at a fit that ended "
                            f"{Status(int(fit.status[i])).name.lower()}; use emcee")


def _sample_emcee(model: ContactModel, rows: np.ndarray, sub: tuple, mode, cov,
                  how: SamplerSettings, out: dict) -> None:
    """emcee for the trials ``rows`` of the batch (``sub``: their :func:`_trial_data`),
    started from their Laplace ``mode`` and ``cov``."""
    nwalkers = how.nwalkers or model.n_params + 1
    fallback = np.diag(np.full(model.n_params, 1e-2))
    covs = np.stack([c if np.all(np.isfinite(c)) else fallback for c in cov])
    # emcee runs in sampling coordinates (log values: see _logpost); the Laplace
    # Gaussian is carried there to first order (the pilot run corrects it).
    x_mode = to_sampling(model, mode)
    jac = fd_slope(lambda u: to_sampling(model, u), mode)
    covs = covs * jac[:, :, None] * jac[:, None, :]
    backends = None
    if how.chains_path is not None:
        require("h5py", "chains_path (emcee's HDF5 chains)")
        backends = [HDFBackend(str(how.chains_path), name=f"trial_{i}") for i in rows]
    workers = available_cores()
    with ThreadPoolExecutor(workers) as pool:
        evaluate = _evaluator(model, sub, pool, workers, rows.size * nwalkers, sampling=True)
        chains = run_lockstep(evaluate, x_mode, covs, nwalkers=nwalkers, seed=how.seed,
                              max_steps=how.max_steps, check_every=how.check_every,
                              min_tau_multiple=how.min_tau_multiple, backends=backends,
                              pilot_steps=how.pilot_steps)
    for i, chain in zip(rows, chains, strict=True):
        _store_emcee(model, i, chain, out)


def _store_emcee(model, i: int, chain, out: dict) -> None:
    """Trial ``i``'s emcee summary (or its failure) into ``out``."""
    out["method"][i] = "emcee"
    if isinstance(chain, BaseException):
        out["reason"][i] = f"emcee failed: {chain}"
        return
    chain.samples = from_sampling(model, chain.samples)
    store_chain(model, i, chain, out)


def store_chain(model, i: int, chain, out: dict) -> None:
    """Row ``i``'s chain (samples in physical units) and its summary into ``out``; a chain
    that did not converge says so in the row's reason."""
    out["chains"][i] = chain
    out["converged"][i] = chain.converged
    out["acceptance"][i] = chain.acceptance
    put_summary(out, i, emcee_summary(model, chain))
    if not chain.converged:
        out["reason"][i] += (f"; NOT CONVERGED after {chain.n_steps} steps (max tau "
                             f"{_largest(chain.tau, '.1f')}, max R-hat "
                             f"{_largest(chain.rhat, '.3f')}, acceptance {chain.acceptance:.2f})")


def _largest(values, fmt: str) -> str:
    """The largest finite entry of ``values``, formatted, or "not estimated"."""
    finite = np.asarray([] if values is None else values, dtype=float)
    finite = finite[np.isfinite(finite)]
    return format(finite.max(), fmt) if finite.size else "not estimated"


