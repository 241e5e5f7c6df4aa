"""Benchmark of posterior uncertainties: speed, error against a long run, calibration.

Simulated 2-s, 1 kHz trials with known truth (20 dB). Every trial is first fitted by
least squares started at the truth, so that what is measured is the uncertainty
method, not the fit's local minima. Then

- **points**: Laplace and emcee at several walker/step budgets on ``n_ref`` trials;
  ``error`` = mean over parameters and the 2.5/16/84/97.5 % quantiles of
  ``|q - q_ref| / sd_ref`` against a long emcee reference run (``4 p`` walkers);
- **calibration**: on ``n_calibration`` trials, the fraction of trial-parameters
  whose true value lies in the 68 % (16-84 %) and 95 % (2.5-97.5 %) intervals, for
  Laplace and for emcee (converged trials only, or all of them when none converged,
  as ``emcee_coverage_over`` says; the converged rate is reported),
  and per parameter, to show where Laplace fails.

Timings are wall-clock medians per trial on a shared machine (see ``machine``).
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from frictionfit.bench._timing import alternate, machine_info, timed
from frictionfit.fit import fit_trials
from frictionfit.models import PARAMS, get_model
from frictionfit.simulation.trials import simulate_trials
from frictionfit.uncertainty import sample_posterior
from frictionfit.uncertainty.posterior import QUANTILES

__all__ = ["run"]

_INTERVALS = ("p2.5", "p16", "p84", "p97.5")


def _fitted(model: str, n: int, seed: int):
    ts = simulate_trials(model, n, seed=seed)
    names = get_model(model).param_names
    u0 = np.stack([PARAMS[p].to_unconstrained(ts.truth[p]) for p in names], axis=-1)
    fit = fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model=model, u0=u0)
    return ts, fit


def _posterior(ts, fit, method: str, seed: int, **kw):
    return sample_posterior(fit, ts.y, ts.t, (ts.t_out, ts.t_back), method=method, seed=seed,
                            **kw)


def _one_by_one(ts, fit, seed: int, **kw) -> SimpleNamespace:
    """emcee one trial at a time (no lockstep batching across trials), for comparison."""
    per_trial = ("model", "values", "stderr", "flags", "u")
    arrays = ("status", "chi2", "redchi", "aic", "bic", "r2", "cond", "n_steps")
    posts = []
    for i in range(fit.n_trials):
        sub = replace(fit, bic_table=None, **{f: [getattr(fit, f)[i]] for f in per_trial},
                      **{f: getattr(fit, f)[i:i + 1] for f in arrays})
        posts.append(sample_posterior(sub, ts.y[i:i + 1], ts.t, (ts.t_out, ts.t_back),
                                      method="emcee", seed=seed + i, **kw))
    return SimpleNamespace(**{k: [getattr(p, k)[0] for p in posts]
                              for k in ("quantiles", "converged", "method", "tau")})


def _interval_error(post, ref) -> float:
    """Mean |quantile - reference quantile| / reference sd over trials, params, quantiles."""
    keys = [list(QUANTILES).index(k) for k in _INTERVALS]
    errs = [np.abs(post.quantiles[i][p][keys] - q[keys]) / ref.sd[i][p]
            for i in range(ref.n_trials) for p, q in ref.quantiles[i].items()]
    return float(np.nanmean(errs))


def _max_tau_median(post) -> float | None:
    """Median over emcee trials of the largest tau (steps); None without emcee trials."""
    taus = [max(t.values()) for m, t in zip(post.method, post.tau, strict=True) if m == "emcee"]
    taus = [x for x in taus if np.isfinite(x)]
    return float(np.median(taus)) if taus else None


def coverage(post, truth: dict[str, np.ndarray], only_converged: bool = True) -> dict:
    """Fractions of trial-parameters inside the 68 % and 95 % intervals (overall, per param)."""
    q = list(QUANTILES)
    hits = {68: {}, 95: {}}
    for i in range(post.n_trials):
        if only_converged and not post.converged[i]:
            continue
        for p, v in post.quantiles[i].items():
            x = truth[p][i]
            hits[68].setdefault(p, []).append(v[q.index("p16")] <= x <= v[q.index("p84")])
            hits[95].setdefault(p, []).append(v[q.index("p2.5")] <= x <= v[q.index("p97.5")])
    out = {}
    for level, per in hits.items():
        flat = [h for hs in per.values() for h in hs]
        out[f"coverage{level}"] = float(np.mean(flat)) if flat else float("nan")
        out[f"coverage{level}_by_param"] = {p: float(np.mean(h)) for p, h in per.items()}
    out["n_trial_params"] = sum(len(h) for h in hits[68].values())
    return out


def run(*, quick: bool = False, seed: int = 0, model: str | None = None,
        n_calibration: int | None = None, n_calibration_emcee: int | None = None,
        n_reference: int | None = None) -> dict:
    """Run the uncertainty benchmark; ``quick=True`` is a small smoke run for tests.

    Parameters
    ----------
    quick : bool
        A few trials of the 5-parameter ``elastic_plastic`` model, small budgets.
    seed : int
        Seed of the simulated trials and of the samplers.
    model : str, optional
        Generating and fitted model; ``"relaxation"`` (full) or ``"elastic_plastic"``
        (quick) by default.
    n_calibration : int, optional
        Calibration trials; 200 (full) or 4 (quick) by default.
    n_calibration_emcee : int, optional
        How many of those trials also get emcee (default: all of them).
    n_reference : int, optional
        Trials of the speed/error table; 8 (full) or 2 (quick) by default.

    Returns
    -------
    dict
        ``{"stage": "uncertainty", "summary": {...}, "points": [...], "machine": {...}}``.
    """
    model = model or ("elastic_plastic" if quick else "relaxation")
    n_cal = n_calibration or (4 if quick else 200)
    p = get_model(model).n_params
    n_ref = n_reference or (2 if quick else 8)
    ref_steps = 600 if quick else 6000
    budgets = [(2 * p + 2, 150), (2 * p + 2, 400)] if quick else [
        (2 * p + 2, 500), (2 * p + 2, 1500), (2 * p + 2, 3000), (4 * p, 3000)]
    ts, fit = _fitted(model, n_ref, seed)
    _posterior(ts, fit, "laplace", seed)  # compile apart, never timed
    ref = _posterior(ts, fit, "emcee", seed + 1, nwalkers=4 * p, max_steps=ref_steps)
    configs = {"laplace": lambda: _posterior(ts, fit, "laplace", seed)}
    for w, s in budgets:
        configs[f"emcee w={w} max_steps={s}"] = (
            lambda w=w, s=s: _posterior(ts, fit, "emcee", seed, nwalkers=w, max_steps=s))
    w, s = budgets[0]
    _one_by_one(ts, fit, seed, nwalkers=w, max_steps=2)  # compile the 1-trial shapes apart
    configs[f"emcee w={w} max_steps={s}, one trial per call (no lockstep)"] = (
        lambda: _one_by_one(ts, fit, seed, nwalkers=w, max_steps=s))
    timing = alternate(configs, repeats=1, warmup=False)
    points = []
    for name, entry in timing.items():
        post = entry["result"]
        points.append({
            "config": name, "seconds_per_trial": entry["median_s"] / n_ref,
            "error": _interval_error(post, ref),
            "error_name": "mean |quantile - reference| / reference sd (2.5/16/84/97.5 %)",
            "converged_rate": float(np.mean(post.converged)),
            "max_tau_median": _max_tau_median(post),
        })
    points.append({"config": "reference", "seconds_per_trial": float("nan"), "error": 0.0,
                   "error_name": "reference itself",
                   "converged_rate": float(np.mean(ref.converged)),
                   "max_tau_median": _max_tau_median(ref)})
    cal_ts, cal_fit = _fitted(model, n_cal, seed + 1000)
    lap_s, lap = timed(lambda: _posterior(cal_ts, cal_fit, "laplace", seed))
    n_mc = min(n_calibration_emcee or n_cal, n_cal)
    sub_ts, sub_fit = (cal_ts, cal_fit) if n_mc == n_cal else _fitted(model, n_mc, seed + 1000)
    cal_steps = 300 if quick else 3000
    mc_s, mc = timed(lambda: _posterior(sub_ts, sub_fit, "emcee", seed, max_steps=cal_steps))
    cov_lap, cov_mc = coverage(lap, cal_ts.truth), coverage(mc, sub_ts.truth)
    mc_over = "converged trials"
    if not mc.converged.any():  # e.g. quick mode: say so rather than report NaN
        cov_mc, mc_over = coverage(mc, sub_ts.truth, only_converged=False), "all (none converged)"
    auto = _posterior(ts, fit, "auto", seed, max_steps=cal_steps)  # the reference trials
    summary = {
        "model": model, "n_calibration": n_cal, "n_reference": n_ref,
        "n_calibration_emcee": n_mc, "emcee_s_per_trial": mc_s / n_mc,
        "laplace_s_per_trial": lap_s / n_cal,
        "coverage68_emcee": cov_mc["coverage68"], "coverage95_emcee": cov_mc["coverage95"],
        "coverage68_laplace": cov_lap["coverage68"],
        "coverage95_laplace": cov_lap["coverage95"],
        "emcee_converged_rate": float(np.mean(mc.converged)),
        "emcee_coverage_over": mc_over,
        "emcee_coverage_by_param": {k: cov_mc[k] for k in ("coverage68_by_param",
                                                          "coverage95_by_param")},
        "laplace_coverage_by_param": {k: cov_lap[k] for k in ("coverage68_by_param",
                                                             "coverage95_by_param")},
        "emcee_max_tau_median": _max_tau_median(mc),
        "emcee_acceptance_median": float(np.nanmedian(mc.acceptance)),
        "auto_emcee_fraction_reference_trials": float(np.mean([m == "emcee" for m in auto.method])),
    }
    return {"stage": "uncertainty", "summary": summary, "points": points,
            "machine": machine_info()}
