"""Calibration of whole-measurement posteriors on simulated measurements with known truth.

``n`` simulated measurements (:func:`~frictionfit.bench.measurement.simulated_measurements`,
every simulator effect on), one channel each, fitted whole with the defaults
(:func:`~frictionfit.whole_fit.fit_recordings`: the law chosen by BIC, the default priors).
Per row, the law parameters of :data:`~frictionfit.bench.measurement.KEY_PARAMS` that its
fit varied are compared with the truth the fit estimates
(:func:`~frictionfit.simulation.measurements.measurement_truth`, in the fit's own units; the
posterior's travel units are taken back to them): the share of row-parameters whose truth
lies in the 68 % (p16-p84) and 95 % (p2.5-p97.5) posterior intervals, per parameter.

- Laplace (``fit.posterior("laplace")``) on every row whose posterior is finite;
- emcee (``fit.posterior("emcee")``, step cap ``emcee_max_steps``) on the first
  ``n_emcee`` rows: over the converged rows (over all of them when none converged, as
  ``whole_emcee_coverage_over`` says) and over all rows; its converged share and wall seconds
  per recording (one lockstep call over the rows, after a short compiling call).

A parameter absent from a row's law (``no_peak2`` has no ``f_static_excess``) or held
fixed there is not counted in that row; the counts per parameter are reported with the
shares.
"""

from __future__ import annotations

import os
from types import SimpleNamespace

import numpy as np

from frictionfit.bench.measurement import KEY_PARAMS, simulated_measurements
from frictionfit.bench.timing import timed
from frictionfit.bench.uncertainty import coverage
from frictionfit.errors import Status
from frictionfit.fit.measurement_data import measurement_data
from frictionfit.fit.result import take_trials
from frictionfit.simulation.measurements import measurement_truth
from frictionfit.whole_fit import fit_recordings

__all__ = ["whole_calibration"]


def _truths(fit, recs: list, channel: str) -> list[dict[str, float]]:
    """Per row, the true value of each key parameter its fit varied, in the fit's own units
    (those of ``fit.values``, as :func:`~frictionfit.bench.measurement.recovery` compares)."""
    return [{p: measurement_truth(r, p, channel) for p in KEY_PARAMS if p in fit.free_names(i)}
            for i, r in enumerate(recs)]


def _scored(post, truths: list[dict[str, float]], rows) -> tuple[SimpleNamespace, dict]:
    """The posterior ``post`` restricted to ``rows`` with a finite posterior and to the key
    parameters of ``truths``, quantiles taken back to the fit's units (``post.unit``), as
    :func:`~frictionfit.bench.uncertainty.coverage` takes it; and the truths, per parameter,
    one value per kept row (NaN where the row lacks it)."""
    kept, quantiles = [], []
    for i in rows:
        q = {p: np.asarray(post.quantiles[i][p], dtype=float) / post.unit(i, p)[1]
             for p in truths[i]}
        if post.method[i] != "none" and q and all(np.all(np.isfinite(v)) for v in q.values()):
            kept.append(i)
            quantiles.append(q)
    view = SimpleNamespace(n_trials=len(kept), quantiles=quantiles,
                           converged=np.array([bool(post.converged[i]) for i in kept]))
    truth = {p: np.array([truths[i].get(p, np.nan) for i in kept]) for p in KEY_PARAMS}
    return view, truth


def _by_param(post, truths: list[dict[str, float]], rows, only_converged: bool = False
              ) -> tuple[dict[str, list[float]], dict[str, int]]:
    """Per key parameter, ``[share in the 68 % interval, share in the 95 % interval]`` over
    ``rows`` (those with a finite posterior; only the converged ones if ``only_converged``),
    and the row-parameters counted."""
    view, truth = _scored(post, truths, rows)
    cov = coverage(view, truth, only_converged=only_converged)
    shares = {p: [cov["coverage68_by_param"][p], cov["coverage95_by_param"][p]]
              for p in KEY_PARAMS if p in cov["coverage68_by_param"]}
    counts = {p: int(sum(p in view.quantiles[k] and (view.converged[k] or not only_converged)
                         for k in range(view.n_trials))) for p in KEY_PARAMS}
    return shares, counts


def _emcee_part(fit, truths: list[dict[str, float]], n_emcee: int, seed: int,
                max_steps: int, pilot_steps: int) -> dict:
    """emcee on the first ``n_emcee`` rows of ``fit``: coverage over the converged rows (all
    of them when none converged) and over all rows, converged share, seconds per recording
    (one call after a compiling one of a few steps) and the load average before it."""
    if n_emcee <= 0:
        return {"coverage": {}, "coverage_all_rows": {}, "n_by_param": {},
                "converged_rate": None, "s_per_recording": None, "over": "skipped",
                "load_average": None}
    sub = take_trials(fit, slice(0, n_emcee))
    sub.posterior("emcee", max_steps=2, pilot_steps=2, seed=seed)  # compiled apart
    load = float(os.getloadavg()[0])
    sec, post = timed(lambda: sub.posterior("emcee", max_steps=max_steps,
                                            pilot_steps=pilot_steps, seed=seed))
    rows = range(n_emcee)
    all_rows, _ = _by_param(post, truths, rows)
    over = "converged rows"
    shares, counts = _by_param(post, truths, rows, only_converged=True)
    if not any(counts.values()):  # none converged: say so rather than report nothing
        over = "all rows (none converged)"
        shares, counts = _by_param(post, truths, rows)
    return {"coverage": shares, "coverage_all_rows": all_rows, "n_by_param": counts,
            "converged_rate": float(np.mean(post.converged)), "s_per_recording": sec / n_emcee,
            "over": over, "load_average": load}


def whole_calibration(n: int, n_emcee: int, *, seed: int = 0, channel: str = "index_x",
                      emcee_max_steps: int = 2000, emcee_pilot_steps: int = 30) -> dict:
    """Coverage of whole-measurement posteriors (Laplace, emcee) per key parameter.

    Parameters
    ----------
    n : int
        Simulated measurements fitted and given Laplace posteriors (one ``channel`` each).
    n_emcee : int
        How many of them (the first) also get emcee; 0 skips emcee.
    seed : int
        Seed of the simulated measurements and of the samplers.
    channel : str
        The channel fitted.
    emcee_max_steps, emcee_pilot_steps : int
        emcee's step cap of the kept chain and steps per adaptation stage.

    Returns
    -------
    dict
        Summary entries, ``whole_``-prefixed: ``whole_coverage_by_param`` (``{"laplace",
        "emcee", "emcee_all_rows"} -> {param: [share in 68 %, share in 95 %]}``), the
        row-parameters counted (``whole_coverage_n_by_param``), the converged shares of the
        fits and of emcee, seconds per recording (Laplace, emcee), the laws chosen.
    """
    recs = simulated_measurements(n, seed)
    items = [measurement_data(r, channel) for r in recs]
    fit_s, fit = timed(lambda: fit_recordings(items, progress=False))
    truths = _truths(fit, recs, channel)
    lap_s, lap = timed(lambda: fit.posterior("laplace", seed=seed))
    lap_cov, lap_n = _by_param(lap, truths, range(n))
    n_emcee = min(n_emcee, n)
    mc = _emcee_part(fit, truths, n_emcee, seed, emcee_max_steps, emcee_pilot_steps)
    return {
        "whole_n": n, "whole_n_emcee": n_emcee, "whole_channel": channel,
        "whole_laws": {m: list(fit.model).count(m) for m in sorted(set(fit.model))},
        "whole_fit_converged_rate": float(np.mean(fit.status == Status.CONVERGED)),
        "whole_fit_s_per_recording_with_compile": fit_s / n,
        "whole_coverage_by_param": {"laplace": lap_cov, "emcee": mc["coverage"],
                                    "emcee_all_rows": mc["coverage_all_rows"]},
        "whole_coverage_n_by_param": {"laplace": lap_n, "emcee": mc["n_by_param"]},
        "whole_laplace_rows": int(sum(m == "laplace" for m in lap.method)),
        "whole_laplace_s_per_recording": lap_s / n,
        "whole_emcee_max_steps": emcee_max_steps,
        "whole_emcee_converged_rate": mc["converged_rate"],
        "whole_emcee_coverage_over": mc["over"],
        "whole_emcee_s_per_recording": mc["s_per_recording"],
        "whole_emcee_load_average": mc["load_average"],
    }
