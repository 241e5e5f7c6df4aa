"""Benchmark of posterior uncertainties: speed, error against a long run, calibration.

Simulated 2-s, 1 kHz trials with known truth (20 dB). Every trial is first fitted by
least squares started at the truth, so that what is measured is the uncertainty
method, not the fit's local minima. Then

- **points** (the walkers/steps table): Laplace and emcee at several walker counts
  and stopping rules on ``n_ref`` trials; ``error`` = mean over parameters and the
  2.5/16/84/97.5 % quantiles of ``|q - q_ref| / sd_ref``, ``sd_error`` = mean
  ``|sd / sd_ref - 1|``, against a long emcee reference run (``4 p`` walkers,
  chain >= 150 tau);
- **calibration**: on ``n_calibration`` trials, the fraction of trial-parameters
  whose true value lies in the 68 % (16-84 %) and 95 % (2.5-97.5 %) intervals, for
  Laplace and for emcee (converged trials only, or all of them when none converged,
  as ``emcee_coverage_over`` says; the converged rate is reported),
  and per parameter, to show where Laplace fails; and Laplace and emcee again with the
  ``ramp`` prior matched to the simulator's spread of true values (intervals are
  calibrated for truths drawn from the prior; the default prior is wider). emcee's time per
  trial is the wall time of a lockstep batch divided by its trials, median over
  ``n_batches`` batches (compile time apart; the load average is recorded with it);
- **whole measurements**: the same coverage for whole-measurement posteriors, per key
  law parameter, Laplace on ``n_whole`` simulated measurements and emcee on the first
  ``n_whole_emcee`` (:mod:`frictionfit.bench.whole_coverage`);
- **downstream**: simulated measurements of library materials (a few motions each,
  signal-to-noise drawn per motion), fitted and given Laplace posteriors; one
  feature vector per measurement from its motions, classified on the same
  stratified folds from (a) point estimates only (mean of the motions' medians),
  (b) inverse-variance weighted means (weights ``1 / sd**2``), (c) point
  estimates plus the pooled posterior sd as extra features.

Timings are wall-clock medians per trial on a shared machine (see ``machine``).
"""

from __future__ import annotations

import os
from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from frictionfit.bench.timing import alternate, machine_info, timed
from frictionfit.fit import Trials, fit_trials
from frictionfit.fit.result import concat_results, take_trials
from frictionfit.models import PARAMS, get_model
from frictionfit.simulation.trials import TRUTH_RANGES, simulate_trials
from frictionfit.uncertainty import sample_posterior
from frictionfit.uncertainty.posterior import QUANTILES

__all__ = ["run"]

_INTERVALS = ("p2.5", "p16", "p84", "p97.5")


def _fitted(model: str, n: int, seed: int, priors=None):
    ts = simulate_trials(model, n, seed=seed)
    names = get_model(model).param_names
    u0 = np.stack([PARAMS[p].to_unconstrained(ts.truth[p]) for p in names], axis=-1)
    fit = fit_trials(_trials(ts), model=model, u0=u0, priors=priors)
    return ts, fit


def _trials(ts, fit=None) -> Trials:
    """The trials of ``ts`` as the fit takes them, or with ``fit``'s channel signs."""
    return Trials.from_arrays(ts.y, ts.t, (ts.t_out, ts.t_back),
                              direction=None if fit is None else fit.direction)


def _simulator_ramp_prior() -> tuple[float, float]:
    """The ``ramp`` prior that matches the simulator's spread of true movement durations:
    median and log-sd of a uniform draw over ``TRUTH_RANGES["ramp"]``."""
    lo, hi, _ = TRUTH_RANGES["ramp"]
    logs = np.log(np.linspace(lo, hi, 1001))
    return float(np.exp(np.median(logs))), float(np.std(logs))


def _posterior(ts, fit, method: str, seed: int, **kw):
    return sample_posterior(fit, _trials(ts, fit), method=method, seed=seed, **kw)


def _one_by_one(ts, fit, seed: int, **kw) -> SimpleNamespace:
    """emcee one trial at a time (no lockstep batching across trials), for comparison."""
    posts, trials = [], _trials(ts, fit)
    for i in range(fit.n_trials):
        posts.append(sample_posterior(take_trials(fit, [i]), trials.take([i]), method="emcee",
                                      seed=seed + i, **kw))
    return SimpleNamespace(**{k: [getattr(p, k)[0] for p in posts]
                              for k in ("quantiles", "sd", "converged", "method", "tau",
                                        "chains")})


def _interval_error(post, ref) -> float:
    """Mean |quantile - reference quantile| / reference sd over trials, params, quantiles."""
    keys = [list(QUANTILES).index(k) for k in _INTERVALS]
    errs = [np.abs(post.quantiles[i][p][keys] - q[keys]) / ref.sd[i][p]
            for i in range(ref.n_trials) for p, q in ref.quantiles[i].items()]
    return float(np.nanmean(errs))


def _sd_error(post, ref) -> float:
    """Mean |sd / reference sd - 1| over trials and parameters."""
    errs = [abs(post.sd[i][p] / ref.sd[i][p] - 1.0)
            for i in range(ref.n_trials) for p in ref.sd[i]]
    return float(np.nanmean(errs))


def _steps_median(post) -> float | None:
    """Median chain length (steps, pilot included) over emcee trials."""
    steps = [c.n_steps + c.n_pilot for c in post.chains if c is not None]
    return float(np.median(steps)) if steps else None


def _load() -> float:
    return float(os.getloadavg()[0])


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
        n_reference: int | None = None, reference_max_steps: int | None = None,
        downstream_size: tuple[int, int, int] | None = None, n_whole: int | None = None,
        n_whole_emcee: int | None = None) -> dict:
    """Run the uncertainty benchmark; ``quick=True`` is a small smoke run for tests.

    Parameters
    ----------
    quick : bool
        A few trials of the 5-parameter ``elastic_plastic`` model, small budgets
        (the reference is then short and usually not converged: a smoke test).
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
    reference_max_steps : int, optional
        Step cap of the long reference run (6000 full, 400 quick).
    downstream_size : (classes, measurements per class, motions), optional
        Size of the downstream classification (35, 10, 4 full; 4, 5, 2 quick).
    n_whole : int, optional
        Simulated whole measurements (``index_x``) of the whole-measurement calibration
        (:func:`~frictionfit.bench.whole_coverage.whole_calibration`), Laplace on all of
        them; 70 (full) or 2 (quick) by default; 0 skips that part.
    n_whole_emcee : int, optional
        How many of those also get emcee (step cap 2000; quick: 20); 12 (full) or 1
        (quick) by default; 0 skips whole-fit emcee.

    Returns
    -------
    dict
        ``{"stage": "uncertainty", "summary": {...}, "points": [...], "machine": {...}}``.
    """
    model = model or ("elastic_plastic" if quick else "relaxation")
    n_cal = n_calibration or (4 if quick else 200)
    p = get_model(model).n_params
    n_ref = n_reference or (2 if quick else 8)
    ts, fit = _fitted(model, n_ref, seed)
    _posterior(ts, fit, "laplace", seed)  # compile apart, never timed
    _posterior(ts, fit, "emcee", seed, max_steps=2, pilot_steps=2)
    ref = _posterior(ts, fit, "emcee", seed + 1, nwalkers=4 * p, min_tau_multiple=150.0,
                     max_steps=reference_max_steps or (400 if quick else 6000))
    cap = 300 if quick else 2000  # step cap of every emcee run but the reference
    points, load_points = _points(ts, fit, ref, seed, p, n_ref, cap, quick)
    calibration = _calibration(model, n_cal, min(n_calibration_emcee or n_cal, n_cal), seed,
                               cap, 1 if quick else 4, ref, load_points)
    auto = _posterior(ts, fit, "auto", seed, max_steps=cap)  # the reference trials
    nc, nm, nmo = downstream_size or (None, None, None)
    down = downstream(quick=quick, seed=seed, n_classes=nc, n_measurements=nm, n_motions=nmo)
    whole = _whole(quick, seed, n_whole, n_whole_emcee)
    summary = {
        "model": model, "n_calibration": n_cal, "n_reference": n_ref, **calibration, **whole,
        "auto_emcee_fraction_reference_trials": float(np.mean([m == "emcee" for m in auto.method])),
        **{k: v for k, v in down.items() if k.startswith("downstream_")},
    }
    return {"stage": "uncertainty", "summary": summary, "points": points,
            "downstream": down, "machine": machine_info()}


def _whole(quick: bool, seed: int, n: int | None, n_emcee: int | None) -> dict:
    """The whole-measurement calibration's summary entries (none when ``n`` is 0)."""
    from frictionfit.bench.whole_coverage import whole_calibration  # it imports this module

    n = (2 if quick else 70) if n is None else n
    if n <= 0:
        return {}
    n_emcee = (1 if quick else 12) if n_emcee is None else n_emcee
    return whole_calibration(n, n_emcee, seed=seed, emcee_max_steps=20 if quick else 2000,
                             emcee_pilot_steps=5 if quick else 30)


def _points(ts, fit, ref, seed: int, p: int, n_ref: int, cap: int, quick: bool
            ) -> tuple[list[dict], float]:
    """The speed/error table: Laplace and emcee at several walker counts and stopping rules
    (steps capped at ``cap``) on the trials ``ts`` (``n_ref`` of them, fitted: ``fit``,
    ``p`` parameters), timed alternately, against the reference run ``ref``; and the load
    average while they ran."""
    configs = {"laplace": lambda: _posterior(ts, fit, "laplace", seed)}
    budgets = [(p + 1, 50.0, None), (2 * p + 2, 50.0, None)]
    if not quick:
        budgets += [(4 * p, 50.0, None), (2 * p + 2, 100.0, None), (2 * p + 2, None, 100)]
    for w, mult, steps in budgets:
        name = f"emcee w={w} " + (f"until {mult:g} tau" if steps is None else f"{steps} steps")
        kw = (dict(min_tau_multiple=mult, max_steps=cap) if steps is None
              else dict(max_steps=steps, min_tau_multiple=1e9))
        configs[name] = lambda w=w, kw=kw: _posterior(ts, fit, "emcee", seed, nwalkers=w, **kw)
    w = 2 * p + 2
    _one_by_one(ts, fit, seed, nwalkers=w, max_steps=2, pilot_steps=2)  # compile 1-trial shapes
    configs[f"emcee w={w} until 50 tau, one trial per call (no lockstep)"] = (
        lambda: _one_by_one(ts, fit, seed, nwalkers=w, max_steps=cap))
    load = _load()
    timing = alternate(configs, repeats=1, warmup=False)
    points = []
    for name, entry in timing.items():
        post = entry["result"]
        points.append({
            "config": name, "seconds_per_trial": entry["median_s"] / n_ref,
            "error": _interval_error(post, ref), "sd_error": _sd_error(post, ref),
            "error_name": "mean |quantile - reference| / reference sd (2.5/16/84/97.5 %)",
            "converged_rate": float(np.mean(post.converged)),
            "max_tau_median": _max_tau_median(post),
            "steps_median": _steps_median(post) if hasattr(post, "chains") else None,
        })
    points.append({"config": "reference", "seconds_per_trial": float("nan"), "error": 0.0,
                   "sd_error": 0.0, "error_name": "reference itself",
                   "converged_rate": float(np.mean(ref.converged)),
                   "max_tau_median": _max_tau_median(ref), "steps_median": _steps_median(ref)})
    return points, (load + _load()) / 2


def _emcee_in_batches(ts, fit, n: int, n_batches: int, seed: int, cap: int):
    """emcee on the ``n`` trials ``ts`` in ``n_batches`` lockstep batches: each batch's wall
    time per trial (s), the posteriors of all of them, and the load average before each."""
    edges = np.linspace(0, n, n_batches + 1).astype(int)
    batch_s, parts, loads = [], [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        bts, bfit = _subset(ts, fit, a, b)
        loads.append(_load())
        sec, part = timed(lambda bts=bts, bfit=bfit, a=a: _posterior(
            bts, bfit, "emcee", seed + a, max_steps=cap))
        batch_s.append(sec / (b - a))
        parts.append(part)
    return batch_s, concat_results(parts), loads


def _with_matched_prior(model: str, cal_ts, n_cal: int, n_mc: int, seed: int, cap: int):
    """The calibration trials fitted again with the ``ramp`` prior matched to the simulator:
    the prior, Laplace's coverage, emcee's posteriors (first ``n_mc`` trials) and their
    coverage."""
    # Credible intervals are calibrated for truths drawn from the prior. The default ramp
    # prior (lab-wide, log sd 0.3) is wider than the simulator's 0.10-0.15 s, so the
    # parameters on the k / ramp / slip_length ridge over-cover; with the prior matched
    # to the simulator they should not.
    matched = _simulator_ramp_prior()
    _, m_fit = _fitted(model, n_cal, seed + 1000, priors={"ramp": matched})
    cov_matched = coverage(_posterior(cal_ts, m_fit, "laplace", seed), cal_ts.truth)
    sub_m_ts, sub_m_fit = _subset(cal_ts, m_fit, 0, n_mc)
    mc_matched = _posterior(sub_m_ts, sub_m_fit, "emcee", seed, max_steps=cap)
    return matched, cov_matched, mc_matched, coverage(mc_matched, sub_m_ts.truth)


def _calibration(model: str, n_cal: int, n_mc: int, seed: int, cap: int, n_batches: int,
                 ref, load_points: float) -> dict:
    """The summary's calibration entries: Laplace's and emcee's coverage on ``n_cal``
    simulated trials (emcee on the first ``n_mc``, in ``n_batches`` timed batches), with the
    default and the matched ``ramp`` prior; with the reference run's converged rate and the
    table's load average (``ref``, ``load_points``) where the summary lists them."""
    cal_ts, cal_fit = _fitted(model, n_cal, seed + 1000)
    lap_s, lap = timed(lambda: _posterior(cal_ts, cal_fit, "laplace", seed))
    sub_ts, sub_fit = _subset(cal_ts, cal_fit, 0, n_mc)
    batch_s, mc, loads = _emcee_in_batches(sub_ts, sub_fit, n_mc, n_batches, seed, cap)
    cov_lap, cov_mc = coverage(lap, cal_ts.truth), coverage(mc, sub_ts.truth)
    matched, cov_matched, mc_matched, cov_mc_matched = _with_matched_prior(
        model, cal_ts, n_cal, n_mc, seed, cap)
    mc_over = "converged trials"
    if not mc.converged.any():  # e.g. quick mode: say so rather than report NaN
        cov_mc, mc_over = coverage(mc, sub_ts.truth, only_converged=False), "all (none converged)"
    cov_mc_all = coverage(mc, sub_ts.truth, only_converged=False)
    by_param = ("coverage68_by_param", "coverage95_by_param")
    return {
        "n_calibration_emcee": n_mc, "emcee_s_per_trial": float(np.median(batch_s)),
        "reference_converged_rate": float(np.mean(ref.converged)),
        "emcee_s_per_trial_batches": batch_s, "emcee_trials_per_batch": int(n_mc // n_batches),
        "emcee_s_per_trial_how": ("wall time of a lockstep batch / its trials, median over "
                                  "batches; pilot and chain included, compile excluded"),
        "load_average_during_emcee": loads, "load_average_during_points": load_points,
        "laplace_s_per_trial": lap_s / n_cal,
        "coverage68_emcee": cov_mc["coverage68"], "coverage95_emcee": cov_mc["coverage95"],
        "coverage68_emcee_all_trials": cov_mc_all["coverage68"],
        "coverage95_emcee_all_trials": cov_mc_all["coverage95"],
        "coverage68_laplace": cov_lap["coverage68"],
        "coverage95_laplace": cov_lap["coverage95"],
        "laplace_matched_ramp_prior": list(matched),
        "coverage68_laplace_matched_prior": cov_matched["coverage68"],
        "coverage95_laplace_matched_prior": cov_matched["coverage95"],
        "laplace_matched_prior_coverage_by_param": {k: cov_matched[k] for k in by_param},
        "coverage68_emcee_matched_prior": cov_mc_matched["coverage68"],
        "coverage95_emcee_matched_prior": cov_mc_matched["coverage95"],
        "emcee_matched_prior_converged_rate": float(np.mean(mc_matched.converged)),
        "emcee_matched_prior_coverage_by_param": {k: cov_mc_matched[k] for k in by_param},
        "emcee_converged_rate": float(np.mean(mc.converged)),
        "emcee_coverage_over": mc_over,
        "emcee_coverage_n_trial_params": cov_mc["n_trial_params"],
        "emcee_coverage_by_param": {k: cov_mc[k] for k in by_param},
        "laplace_coverage_by_param": {k: cov_lap[k] for k in by_param},
        "emcee_max_tau_median": _max_tau_median(mc),
        "emcee_steps_median": _steps_median(mc),
        "emcee_acceptance_median": float(np.nanmedian(mc.acceptance)),
    }


def _subset(ts, fit, a: int, b: int):
    """Trials ``a:b`` of a trial set and its fit."""
    sub_fit = take_trials(fit, slice(a, b))
    sub_ts = replace(ts, y=ts.y[a:b], direction=ts.direction[a:b],
                     truth={k: v[a:b] for k, v in ts.truth.items()}, noise_sd=ts.noise_sd[a:b])
    return sub_ts, sub_fit


#: Law parameters used as material features (the drive's delay/ramp and the offset are not).
_LAW = ("k", "f_kin", "f_static_excess", "slip_length", "relax_frac", "tau")


def downstream(*, quick: bool = False, seed: int = 0, n_classes: int | None = None,
               n_measurements: int | None = None, n_motions: int | None = None,
               snr_db: tuple[float, float] = (3.0, 30.0)) -> dict:
    """Material classification from point estimates vs uncertainty-aware features.

    Each measurement of a library material has ``n_motions`` motions (trials) whose
    law parameters are drawn around the material's values (library spreads) and whose
    signal-to-noise ratio is drawn uniformly in ``snr_db``: some motions are much
    better measured than others, which is what posterior sds can tell apart. Every
    motion is fitted (``relaxation``, default start, not the truth) and given a
    Laplace posterior; features per measurement, per law parameter (log units for
    log-scaled ones): ``point`` = mean of the motions' medians; ``ivw`` = the
    inverse-variance weighted mean (weights ``1 / sd**2``, sd from the 16-84 %
    interval); ``with_sd`` = ``point`` plus log of the pooled sd;
    ``point_median`` = median of the motions' medians (a robust point baseline). Same
    ``StratifiedKFold`` folds (5, shuffled, seeded) and RBF SVM for all three.
    """
    from frictionfit.simulation.materials import CLASSES

    n_classes = n_classes or (4 if quick else len(CLASSES))
    n_meas = n_measurements or (5 if quick else 10)
    n_mot = n_motions or (2 if quick else 4)
    model = get_model("relaxation")
    rng = np.random.default_rng(seed + 7)
    labels = list(CLASSES[:: max(1, len(CLASSES) // n_classes)][:n_classes])
    rows, meas_label = _motion_truths(labels, n_meas, n_mot, rng)
    trials = _noisy_trials(model, rows, snr_db, rng)
    fit_s, fit = timed(lambda: fit_trials(trials, model="relaxation"))
    post_s, post = timed(lambda: sample_posterior(fit, trials, method="laplace"))
    n_meas_total = len(meas_label)
    med, sd = _medians_and_sds(post, len(rows))
    feats = _measurement_features(med.reshape(n_meas_total, n_mot, -1),
                                  sd.reshape(n_meas_total, n_mot, -1))
    acc = _cv_accuracy(feats, np.asarray(meas_label), seed)
    return {
        "downstream_accuracy_point": acc["point"],
        "downstream_accuracy_point_median": acc["point_median"],
        "downstream_accuracy_ivw": acc["ivw"],
        "downstream_accuracy_with_sd": acc["with_sd"],
        "downstream_n_classes": len(labels), "downstream_n_measurements": n_meas_total,
        "downstream_motions_per_measurement": n_mot, "downstream_snr_db": list(snr_db),
        "downstream_fit_converged_rate": float(np.mean(fit.status == 0)),
        "downstream_fit_s": fit_s, "downstream_laplace_s": post_s,
        "downstream_folds": "StratifiedKFold(5, shuffle, seeded), identical for all features",
        "downstream_classifier": "StandardScaler + RBF SVM (svm-ovo)",
        "downstream_uncertainty": "laplace",
    }


def _motion_truths(labels: list[str], n_meas: int, n_mot: int, rng: np.random.Generator
                   ) -> tuple[list[dict[str, float]], list[str]]:
    """Per motion (``n_mot`` per measurement, ``n_meas`` measurements per material of
    ``labels``), its true law parameters (drawn around the material's values) and drive;
    and each measurement's label."""
    from frictionfit.simulation.materials import draw_parameters, material_for
    from frictionfit.simulation.trials import TRUTH_RANGES, _draw

    rows, meas_label = [], []
    for label in labels:
        mat = material_for(label)
        for _ in range(n_meas):
            meas_label.append(label)
            for _ in range(n_mot):
                law = draw_parameters(mat, rng, {})
                v = {n: law[n] for n in _LAW}
                for n in ("offset", "delay", "ramp"):
                    v[n] = float(_draw(rng, n, 1)[0]) if n in TRUTH_RANGES else 0.0
                rows.append(v)
    return rows, meas_label


def _noisy_trials(model, rows: list[dict[str, float]], snr_db: tuple[float, float],
                  rng: np.random.Generator) -> Trials:
    """One simulated 2-s trial per row of true parameters, its direction drawn at random and
    white noise added at a signal-to-noise ratio (dB) drawn uniformly in ``snr_db``."""
    t = np.arange(2000) / 1000.0
    t_out, t_back = 0.05, 1.05
    u = np.stack([[PARAMS[n].to_unconstrained(r[n]) for n in model.param_names] for r in rows])
    direction = rng.choice([-1.0, 1.0], len(rows))
    clean = _predict_batch(model, u, t, t_out, t_back, direction)
    rms = np.sqrt(np.mean((clean - clean.mean(axis=1, keepdims=True)) ** 2, axis=1))
    snr = rng.uniform(*snr_db, len(rows))
    y = clean + (rms / 10 ** (snr / 20))[:, None] * rng.standard_normal(clean.shape)
    return Trials.from_arrays(y, t, (t_out, t_back))


def _medians_and_sds(post, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per trial (of ``n``) and law parameter of :data:`_LAW`, the posterior median and sd
    (half the 16-84 % interval), in log units for log-scaled parameters; (n, len(_LAW))."""
    q16, q50, q84 = (list(QUANTILES).index(k) for k in ("p16", "median", "p84"))
    med = np.full((n, len(_LAW)), np.nan)
    sd = np.full_like(med, np.nan)
    for i in range(n):
        for j, name in enumerate(_LAW):
            q = np.asarray(post.quantiles[i][name], dtype=float)
            if PARAMS[name].transform == "loglogit":
                q = np.log(np.maximum(q, 1e-300))
            med[i, j], sd[i, j] = q[q50], 0.5 * (q[q84] - q[q16])
    return med, sd


def _measurement_features(med: np.ndarray, sd: np.ndarray) -> dict[str, np.ndarray]:
    """The feature sets per measurement from its motions' medians and sds (measurement,
    motion, parameter): ``point``, ``point_median``, ``ivw`` and ``with_sd``."""
    ok = np.isfinite(med) & np.isfinite(sd) & (sd > 0)
    w = np.where(ok, 1.0 / np.where(ok, sd, 1.0) ** 2, 0.0)
    okm = np.where(ok, med, 0.0)
    n_ok = np.maximum(ok.sum(axis=1), 1)
    point = okm.sum(axis=1) / n_ok
    ivw = (w * okm).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-300)
    pooled_sd = 1.0 / np.sqrt(np.maximum(w.sum(axis=1), 1e-300))
    point_median = np.nanmedian(np.where(ok, med, np.nan), axis=1)  # robust point baseline
    return {"point": point, "point_median": point_median, "ivw": ivw,
            "with_sd": np.hstack([point, np.log(np.maximum(pooled_sd, 1e-300))])}


def _cv_accuracy(feats: dict[str, np.ndarray], yl: np.ndarray, seed: int) -> dict[str, float]:
    """Per feature set, the mean accuracy of a scaled RBF SVM over the same five shuffled,
    seeded stratified folds."""
    from sklearn.model_selection import StratifiedKFold
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from frictionfit.classify import make_classifier

    folds = list(StratifiedKFold(5, shuffle=True, random_state=seed).split(feats["point"], yl))
    acc = {}
    for name, X in feats.items():
        X = np.nan_to_num(X, nan=0.0, posinf=0.0, neginf=0.0)
        hits = []
        for train, test in folds:
            clf = make_pipeline(StandardScaler(), make_classifier("svm-ovo", seed=seed))
            clf.fit(X[train], yl[train])
            hits.append(np.mean(clf.predict(X[test]) == yl[test]))
        acc[name] = float(np.mean(hits))
    return acc


def _predict_batch(model, u, t, t_out, t_back, direction) -> np.ndarray:
    import jax
    import jax.numpy as jnp

    tj = jnp.asarray(t)

    def one(ui, d):
        return model.predict(ui, tj, (t_out, t_back), d)

    return np.asarray(jax.jit(jax.vmap(one))(jnp.asarray(u), jnp.asarray(direction)))
