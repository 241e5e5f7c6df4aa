"""Posteriors of whole fits: Laplace and emcee.

:func:`whole_fit_posterior` takes a :class:`~frictionfit.fit.MeasurementFit` (which keeps
its data) and returns a :class:`~frictionfit.uncertainty.Posterior`, one row per recording
x channel.

The density is the fit's own, the one likelihood's long-run form for whole fits
(:mod:`frictionfit.fit._noise`): its residual (weighted block residuals, then the model's
prior rows scaled by the recording's noise sd) over the long-run variance of the AR(1)
noise the fit estimated at its optimum (``MeasurementFit.noise_var``). Its mode is the
fit's optimum and its Gauss-Newton covariance ``MeasurementFit.density_cov``. The fit's
covariance ``MeasurementFit.cov`` is the sandwich around that optimum, which takes each
parameter's own share of the residuals' correlation; both methods report it: Laplace is
its Gaussian, and emcee's draws ``v`` are carried to it by the affine map
``u_hat + M (v - u_hat)``, ``M density_cov M^T = cov`` (the curvature adjustment of
Chandler & Bate 2007: the density sampled is the long-run one with its coordinates
stretched about its mode).

- ``"laplace"``: draws from ``N(u_hat, cov)`` over the free parameters in the fit's
  unconstrained coordinates, mapped to physical units; quantiles and sd of the draws.
- ``"emcee"``: the density above, flat on the bounds of the sampling coordinates (the log
  of ``loglogit`` parameters, the value of ``logit`` ones), sampled in the fit's
  unconstrained ``u`` (times the logistic Jacobian: a value on its bound is no wall there,
  and the density has its mode inside), all recordings' walkers in one ensemble with
  :func:`~frictionfit.uncertainty._ensemble.run_lockstep` (adaptive independence proposal,
  started from a Gauss-Newton mode and covariance in ``u``, each recording run to >=
  ``min_tau_multiple`` integrated autocorrelation times with its walkers agreeing,
  R-hat <= 1.01), the density evaluated on the host by the model's compiled loop, every
  walker of a step in one call; its chain statistics are the sampled density's.
- ``"auto"``: Laplace, and emcee for the rows the per-motion policy distrusts (fit not
  ``CONVERGED``, a parameter "at bound" or "singular", condition number above
  :data:`~frictionfit.uncertainty.AUTO_MAX_COND`, a non-Gaussian profile).

Fixed and tied parameters stay at the fit's values: neither method samples them. Values a
fit holds at its session's (``rig="session"``: the motor's profile; ``creep="session"``:
the finger's creep) carry their own uncertainty in: Laplace through ``cov``, which includes
it; emcee samples the free parameters at the held values and shifts each draw by an
independent draw of ``N(0, held_cov)`` (``MeasurementFit.held_cov``: what the holds add to
``cov``, to first order) before its quantiles and sd are taken; its chain and chain
statistics stay those of the sampled density. Rows whose fit failed (non-finite,
too little data, no finite covariance) get method ``"none"``, the reason, NaN numbers and
``converged=False``.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from dataclasses import replace
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.errors import FitError, Status
from frictionfit.fit._stats import VANISHING
from frictionfit.fit._whole_problem import WholeFitData, normal_fn, profile_drops, stack_items
from frictionfit.fit.measurement_data import MeasurementData
from frictionfit.fit.whole_result import MeasurementFit
from frictionfit.models import PARAMS, MeasurementModel
from frictionfit.models.measurement import jit_host_loop
from frictionfit.uncertainty._ensemble import ChainResult, run_lockstep
from frictionfit.uncertainty._logpost import log_logistic
from frictionfit.uncertainty.engine import (
    METHODS,
    auto_reason,
    blank_rows,
    emcee_summary,
    nan_summary,
    put_summary,
    store_chain,
)
from frictionfit.uncertainty.posterior import Posterior

__all__ = ["measurement_posterior", "whole_fit_posterior"]

#: Chain lengths at which a whole fit's slowly mixing chain is refitted and restarted
#: (:func:`~frictionfit.uncertainty._ensemble.run_lockstep`): only the early ones. Its
#: chains' autocorrelation times (100-200 steps with every proposal tried) need more steps
#: than the cap allows, and each later restart would add its length to their time.
WHOLE_REFIT_AT = (100, 200)

_SKIP = (Status.NONFINITE, Status.INSUFFICIENT_DATA)


def _bounded(model: MeasurementModel, free: tuple[int, ...]) -> np.ndarray:
    """Which free parameters are bounded (a logistic map between ``u`` and the value)."""
    return np.array([model.params[j].transform != "identity" for j in free])


def _density(model: MeasurementModel, free: tuple[int, ...], data: WholeFitData,
             s2: np.ndarray):
    """``f(U (R, q), idx (R,)) -> (R,)``: the log density at the free parameters ``U`` (the
    fit's unconstrained coordinates) of items ``idx`` of ``data``, flat on the bounds of
    each parameter's sampling coordinate (value or log value) and carried to ``u`` (its
    logistic Jacobian); ``s2`` (per item) the long-run noise variance (N^2). On the host by
    the compiled loop (no JAX): emcee's density."""
    bounded, free_l = _bounded(model, free), list(free)

    def evaluate(u_free: np.ndarray, idx: np.ndarray) -> np.ndarray:
        u = data.base[idx]
        u[:, free_l] = u_free
        cost = model.weighted_cost(u, data.t[idx], data.commands[idx], data.signs[idx],
                                   data.stretch[idx], data.direction[idx], data.y[idx],
                                   data.weight[idx])
        prior = data.noise[idx, None] * model.prior_residuals(u)
        lp = (-(cost + 0.5 * np.sum(prior**2, axis=-1)) / s2[idx]
              + np.sum(np.where(bounded, log_logistic(u_free), 0.0), axis=-1))
        return np.where(np.isfinite(lp), lp, -np.inf)

    return evaluate


def _profile_disagreement(model, free, data: WholeFitData, s2: np.ndarray, mode: np.ndarray,
                          cov: np.ndarray) -> np.ndarray:
    """Per item, max over free parameters and sides of ``|drop - 2|`` of the log density
    2 sd out along the parameter's Gaussian profile line (0 for an exact Gaussian; inf where
    the density is not finite there)."""
    dev = np.abs(profile_drops(model, free, mode, cov, data, np.asarray(s2),
                               range(mode.shape[0])) - 2.0)
    return np.max(np.where(np.isnan(dev), np.inf, dev), axis=(1, 2))


def _laplace_draws(mode: np.ndarray, cov: np.ndarray, n_draws: int,
                   rng: np.random.Generator) -> np.ndarray:
    """``n_draws`` draws of ``N(mode, cov)`` (eigen-factor: exact for a semidefinite cov)."""
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    z = rng.standard_normal((n_draws, mode.size))
    return mode + (z * np.sqrt(np.maximum(w, 0.0))) @ v.T


def _laplace_summary(model: MeasurementModel, draws: np.ndarray) -> dict:
    """Quantiles and sd (physical) of full unconstrained ``draws (n, p)``; the chain
    statistics NaN (independent draws)."""
    nan = np.full(model.n_params, np.nan)
    summary = emcee_summary(
        model, ChainResult(draws[:, None, :], nan, len(draws), 0, 1, np.nan, False))
    return nan_summary(model.param_names) | {k: summary[k] for k in ("quantiles", "sd")}


def whole_fit_posterior(
    fit: MeasurementFit, *, method: str = "laplace", n_draws: int = 4000,
    nwalkers: int | None = None, max_steps: int = 2000, check_every: int = 25,
    min_tau_multiple: float = 50.0, pilot_steps: int = 30, seed: int = 0,
) -> Posterior:
    """Posterior of every row of a whole fit, by Laplace and/or emcee.

    Parameters
    ----------
    fit : MeasurementFit
        A whole fit (:func:`frictionfit.fit_recordings`); its data and noise are its own.
    method : {"laplace", "auto", "emcee"}
        See the module docstring.
    n_draws : int
        Laplace draws per row.
    nwalkers : int, optional
        emcee walkers per row; default ``n_free + 1`` (each walker is a chain of its own: the
        proposal moves it alone).
    max_steps, check_every, min_tau_multiple, pilot_steps
        emcee: step cap of the kept chain, steps between tau checks, required chain length
        in tau, steps of each adaptation stage.
    seed : int
        Seed of the Laplace draws and of the emcee walkers and moves (one stream per
        batch: a row's emcee draws depend on the rows sampled with it).

    Returns
    -------
    Posterior
        One entry per row (physical units); ``chains[i]`` holds emcee's chain carried to the
        fit's covariance, in the fit's unconstrained coordinates of every parameter (fixed
        and held ones constant; the held values' spread is in the quantiles and sd, not in
        the chain).

    Examples
    --------
    >>> import frictionfit
    >>> from frictionfit.simulation.measurements import simulate_measurements
    >>> rec, = simulate_measurements([(1, "paper-2", 1)], seed=3)
    >>> fit = frictionfit.fit_recordings([rec], channels=["index_x"], progress=False)
    >>> whole_fit_posterior(fit, method="laplace").method
    ['laplace']
    """
    if not isinstance(fit, MeasurementFit):
        raise FitError(f"whole_fit_posterior needs a whole fit (MeasurementFit), not "
                       f"{type(fit).__name__} (use sample_posterior)")
    if method not in METHODS:
        raise FitError(f"unknown uncertainty method {method!r}; choose from {METHODS}")
    start = time.perf_counter()
    n = fit.n_trials
    out = blank_rows(n)
    groups: dict = {}
    for i in range(n):
        model = fit.member(i)
        free = tuple(model.param_names.index(p) for p in fit.free_names(i))
        put_summary(out, i, nan_summary(model.param_names))
        why = _unusable(fit, i)
        if why:
            out["reason"][i] = f"skipped: {why}"
        else:
            groups.setdefault((model, free), []).append(i)
    rng = np.random.default_rng(seed)
    for (model, free), rows in groups.items():
        _sample_group(fit, model, free, np.array(rows), method, n_draws, rng, out,
                      dict(nwalkers=nwalkers or len(free) + 1, seed=seed,
                           max_steps=max_steps, check_every=check_every,
                           min_tau_multiple=min_tau_multiple, pilot_steps=pilot_steps,
                           refit_at=WHOLE_REFIT_AT))
    units = [_in_reported_units(fit, i, out) for i in range(n)]
    return Posterior(model=list(fit.model), wall_s=time.perf_counter() - start, units=units,
                     **out)


def _in_reported_units(fit: MeasurementFit, i: int, out: dict) -> dict:
    """Row ``i``'s quantiles and sd put in the units the fit reports (:meth:`MeasurementFit.
    unit`); the parameters whose unit that changes, ``name -> (unit, factor)``."""
    units = {}
    for name in out["quantiles"][i]:
        unit, scale = fit.unit(i, name)
        if (unit, scale) != (PARAMS[name].unit, 1.0):
            units[name] = (unit, scale)
            out["quantiles"][i][name] = np.asarray(out["quantiles"][i][name]) * scale
            out["sd"][i][name] = out["sd"][i][name] * scale
    return units


def measurement_posterior(fit: MeasurementFit, items: Sequence[MeasurementData] | None = None,
                          **kw) -> Posterior:
    """Deprecated: the fit's ``.posterior(method=...)`` (:func:`whole_fit_posterior`);
    ``items`` is not needed (the fit keeps its data) and must match it if given."""
    warnings.warn("measurement_posterior is deprecated and will be removed in the next "
                  "release; use the fit's .posterior()", DeprecationWarning, stacklevel=2)
    if items is not None and len(items) != fit.n_trials:
        raise FitError(f"{len(items)} items but the fit has {fit.n_trials} rows")
    return whole_fit_posterior(fit, **kw)


def _unusable(fit: MeasurementFit, i: int) -> str:
    """Why row ``i`` has no posterior ("" when it can be sampled)."""
    if Status(int(fit.status[i])) in _SKIP:
        return f"fit status {Status(int(fit.status[i])).name.lower()}"
    if not np.all(np.isfinite(fit.u[i])):
        return "non-finite optimum"
    if fit.cov is None or not np.all(np.isfinite(fit.cov[i])):
        return "covariance not finite (a parameter the data do not determine: see the flags)"
    return ""


def _sample_group(fit: MeasurementFit, model: MeasurementModel, free: tuple[int, ...],
                  rows: np.ndarray, method: str, n_draws: int, rng: np.random.Generator,
                  out: dict, emcee_kw: dict) -> None:
    """Laplace for the rows of one model and free set, then emcee where ``method`` asks."""
    u_hat = np.stack([fit.u[i] for i in rows])
    free_l = list(free)
    mode, cov = u_hat[:, free_l], np.stack([fit.cov[i] for i in rows])
    if method != "laplace":  # the density is needed
        data = stack_items([fit.items[i] for i in rows], u_hat)
        s2 = np.asarray(fit.noise_var[rows])
    if method == "auto":
        dev = _profile_disagreement(model, free, data, s2, mode,
                                    np.stack([_density_cov(fit, i) for i in rows]))
        reasons = [auto_reason(fit, i, fit.cond[i], dev[k]) for k, i in enumerate(rows)]
    else:
        reasons = [method] * rows.size
    use_emcee = np.array([method == "emcee" or bool(r) for r in reasons]) & (method != "laplace")
    for k, i in enumerate(rows):
        out["reason"][i] = reasons[k] or "laplace ok"
        if not use_emcee[k]:
            draws = np.repeat(u_hat[k][None], n_draws, axis=0)
            draws[:, free_l] = _laplace_draws(mode[k], cov[k], n_draws, rng)
            _store_laplace(fit, model, i, draws, out)
    sel = np.flatnonzero(use_emcee)
    if sel.size:
        held = [_held_cov(fit, i) for i in rows]
        maps = [_sandwich_map(_density_cov(fit, i), fit.cov[i] - held[k])
                for k, i in enumerate(rows)]
        _sample_emcee(model, free, data, s2, u_hat, (maps, held), sel, rows, out, emcee_kw,
                      rng)


def _held_cov(fit: MeasurementFit, i: int) -> np.ndarray:
    """Row ``i``'s :attr:`~frictionfit.fit.MeasurementFit.held_cov` (zeros for a fit that
    does not record it)."""
    p = len(fit.free_names(i))
    held = None if fit.held_cov is None else fit.held_cov[i]
    return np.zeros((p, p)) if held is None else np.asarray(held)


def _density_cov(fit: MeasurementFit, i: int) -> np.ndarray:
    """Row ``i``'s :attr:`~frictionfit.fit.MeasurementFit.density_cov` (``cov`` less the
    held share for a fit that does not record it)."""
    if fit.density_cov is None or fit.density_cov[i] is None:
        return np.asarray(fit.cov[i]) - _held_cov(fit, i)
    return np.asarray(fit.density_cov[i])


def _root(cov: np.ndarray, power: float) -> tuple[np.ndarray, np.ndarray]:
    """``cov^power`` of a symmetric semidefinite ``cov`` on its range, and the projector on
    its null space."""
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    keep = w > 1e-13 * max(w.max(initial=0.0), 1e-300)
    return (v * np.where(keep, w, 1.0) ** power * keep) @ v.T, (v * ~keep) @ v.T


def _sandwich_map(density_cov: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``M`` with ``M density_cov M^T = cov`` on ``density_cov``'s range, ``cov^(1/2)
    density_cov^(-1/2)`` (symmetric roots), and the identity on its null space (a
    parameter the density does not curve, such as one on its bound, keeps its draws)."""
    inverse_root, null = _root(density_cov, -0.5)
    return _root(cov, 0.5)[0] @ inverse_root + null


def _store_laplace(fit: MeasurementFit, model, i: int, draws: np.ndarray, out: dict) -> None:
    out["method"][i] = "laplace"
    put_summary(out, i, _laplace_summary(model, draws))
    out["converged"][i] = int(fit.status[i]) == Status.CONVERGED
    pinned = [n for n, f in fit.flags[i].items() if f in VANISHING]
    if pinned:  # the Gaussian has (almost) no width there: no interval
        out["reason"][i] += f"; no interval for {', '.join(pinned)} (at bound or singular)"
    if not out["converged"][i]:
        out["reason"][i] = (f"laplace at a fit that ended "
                            f"{Status(int(fit.status[i])).name.lower()}; use emcee")


#: Where a bounded parameter's ``u`` lies beyond this (a value on its bound), the search for
#: the mode of the density in ``u`` starts from here: that density (the flat one times the
#: logistic Jacobian) has its mode inside, not at infinity.
_U_START = 5.0


@lru_cache(maxsize=16)
def _gauss_newton_fn(model: MeasurementModel, free: tuple[int, ...]):
    """Jitted ``(u_free, data, s2, bounded) -> (log density, gradient, Gauss-Newton
    Hessian)`` of one item's density in ``u`` (:func:`_density`), the logistic Jacobian's
    terms exact."""
    normal = normal_fn(model, free)

    def one(u, data, s2, bounded):
        cost, jtj, jtr = normal(u, data)
        sig = jax.nn.sigmoid(u)
        lp = -cost / s2 + jnp.sum(jnp.where(bounded, log_logistic(u), 0.0))
        grad = -jtr / s2 + jnp.where(bounded, 1.0 - 2.0 * sig, 0.0)
        hess = jtj / s2 + jnp.diag(jnp.where(bounded, 2.0 * sig * (1.0 - sig), 0.0))
        return lp, grad, hess

    return jit_host_loop(one)


def _proposal_start(model: MeasurementModel, free: tuple[int, ...], u_free: np.ndarray,
                    data: WholeFitData, s2: np.ndarray, steps: int = 12,
                    max_step: float = 2.0
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per item, the mode and covariance of emcee's first proposal in ``u``: damped
    Gauss-Newton steps (at most ``max_step`` in ``u``, halved until the density rises) from
    the fit's optimum with bounded parameters moved within ``+-_U_START``, and the inverse of
    the Gauss-Newton Hessian there plus the logistic density's precision (``3 / pi^2``) on
    bounded parameters: a floor that gives width to a parameter the data barely see (one on
    its bound, whose column of the fit's covariance is 0). ``s2``: per item, the long-run
    noise variance (N^2)."""
    bounded = _bounded(model, free)
    gn = _gauss_newton_fn(model, free)
    floor = np.diag(np.where(bounded, 3.0 / np.pi**2, 0.0))
    mode = np.where(bounded, np.clip(u_free, -_U_START, _U_START), u_free)
    covs = np.empty((len(mode), len(free), len(free)))
    for k in range(len(mode)):
        row = data.take(k)
        lp, grad, hess = (np.asarray(a) for a in gn(jnp.asarray(mode[k]), row, s2[k], bounded))
        for _ in range(steps):
            step = np.linalg.solve(hess + floor, grad)
            step *= min(1.0, max_step / max(np.max(np.abs(step)), 1e-300))
            for _ in range(10):  # halve until the density rises
                new = [np.asarray(a) for a in gn(jnp.asarray(mode[k] + step), row, s2[k],
                                                  bounded)]
                if new[0] > lp:
                    break
                step = 0.5 * step
            else:
                break
            mode[k] = mode[k] + step
            lp, grad, hess = new
        covs[k] = np.linalg.inv(hess + floor)
    return mode, covs


def _carried(chain: ChainResult, free_l: list[int], centre: np.ndarray,
             sandwich_map: np.ndarray) -> ChainResult:
    """``chain`` with each draw ``v`` of the free parameters carried to the fit's covariance:
    ``centre + sandwich_map (v - centre)`` (an affine map: a chain of the adjusted density,
    its statistics the sampled one's)."""
    samples = chain.samples.copy()
    samples[..., free_l] = centre + (samples[..., free_l] - centre) @ sandwich_map.T
    return replace(chain, samples=samples)


def _with_held_spread(chain: ChainResult, free_l: list[int], held_cov: np.ndarray,
                      rng: np.random.Generator) -> ChainResult:
    """``chain`` with each draw of the free parameters shifted by an independent draw of
    ``N(0, held_cov)`` (unconstrained coordinates): the spread that values held at the
    session's add, to first order, to a posterior sampled at those values. The chain
    statistics stay those of the chain itself."""
    if not np.any(held_cov):
        return chain
    shape = (*chain.samples.shape[:2], len(free_l))
    samples = chain.samples.copy()
    samples[..., free_l] += _laplace_draws(np.zeros(len(free_l)), held_cov,
                                           int(np.prod(shape[:2])), rng).reshape(shape)
    return replace(chain, samples=samples)


def _sample_emcee(model, free, data: WholeFitData, s2: np.ndarray, u_hat, spread: tuple,
                  sel, rows, out, kw: dict, rng: np.random.Generator) -> None:
    """emcee for the group's rows ``sel`` in the fit's unconstrained coordinates (the density
    flat on the bounds of the sampling coordinates, times the logistic Jacobian), started
    from :func:`_proposal_start` (the pilot stages refit the proposal); each row's summary
    taken of its draws carried to the fit's covariance (:func:`_carried`; the chain kept so)
    and widened by its held share (:func:`_with_held_spread`); ``spread``: per row of the
    group, the maps and ``held_cov``."""
    maps, held_cov = spread
    free_l = list(free)
    sub = data.take(sel)
    centre, covs = _proposal_start(model, free, u_hat[sel][:, free_l], sub, s2[sel])
    chains = run_lockstep(_density(model, free, sub, s2[sel]), centre, covs, **kw)
    for k, chain in zip(sel, chains, strict=True):
        i = rows[k]
        out["method"][i] = "emcee"
        if isinstance(chain, BaseException):
            out["reason"][i] = f"emcee failed: {chain}"
            out["converged"][i] = False
            put_summary(out, i, nan_summary(model.param_names))
            continue
        full = np.broadcast_to(u_hat[k], (*chain.samples.shape[:2], model.n_params)).copy()
        full[..., free_l] = chain.samples
        chain.samples = full
        for key in ("tau", "rhat"):  # fixed parameters: no chain statistics
            full_stat = np.full(model.n_params, np.nan)
            full_stat[free_l] = getattr(chain, key)
            setattr(chain, key, full_stat)
        chain = _carried(chain, free_l, u_hat[k, free_l], maps[k])
        store_chain(model, i, _with_held_spread(chain, free_l, held_cov[k], rng), out)
        out["chains"][i] = chain
