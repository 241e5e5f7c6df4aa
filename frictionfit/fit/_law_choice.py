"""The law chosen per item among those a whole fit tries (``model="auto"``), and where each
law after the first starts from.

One law is fitted from the data; each other law is fitted from an optimum, on the items
where it can still be chosen (:data:`GROWN_FROM`, :data:`SHRUNK_FROM`). Per item the first
law (simplest first) whose BIC is within :data:`~frictionfit.fit._stats.BIC_TIE` of the
best is chosen, a law without a static peak only where no law's peak stands out of its
noise (:data:`PEAK_Z`). The BIC is the one likelihood's (:mod:`frictionfit.fit._noise`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from frictionfit.fit._stats import choose
from frictionfit.fit.measurement_data import MeasurementData
from frictionfit.fit.result import FitResult, concat_results, take_trials
from frictionfit.models import MeasurementModel
from frictionfit.models.measurement import to_unconstrained

__all__ = ["AUTO_LAWS", "DAMPING_START", "GROWN_FROM", "PEAK_Z", "SHRUNK_FROM", "by_bic",
           "choice", "from_optimum", "held_of", "in_order", "origin", "peak_measured"]

#: The laws ``model="auto"`` chooses from, simplest first.
AUTO_LAWS = ("no_peak2", "relaxation2", "rich")
#: Law -> the smaller law whose optimum it is fitted from (with that law's drive): viscous
#: ``damping`` fitted from the data's guess, or with the others far from their optimum,
#: falls to its lower bound (a log coordinate runs away from where it acts), so ``rich``
#: starts from ``relaxation2``'s optimum with the damping at :data:`DAMPING_START`.
GROWN_FROM = {"rich": "relaxation2"}
#: Law -> the larger law whose optimum it is fitted from where both are chosen from: the
#: law without a static peak is ``relaxation2`` at ``f_static_excess = 0``, so it is fitted
#: only where ``relaxation2``'s peak is not measured (:data:`PEAK_Z`), from that optimum
#: with the peak's mean share over a stroke moved into the kinetic level.
SHRUNK_FROM = {"no_peak2": "relaxation2"}
#: The damping a grown ``rich`` starts from (N s/mm): this fraction of ``f_kin`` over the
#: movement's mean speed (``stroke_mm / ramp``), a viscous force of ~1 % of the kinetic level.
DAMPING_START = 0.01

def origin(model: MeasurementModel, models: Sequence[MeasurementModel]
            ) -> MeasurementModel | None:
    """The law whose optimum ``model`` is fitted from (:data:`GROWN_FROM`: same stroke, the
    priors on its parameters; :data:`SHRUNK_FROM`, where that law is among ``models``), or
    ``None`` (fitted from the data)."""
    larger = [m for m in models if m.law == SHRUNK_FROM.get(model.law)]
    if larger:
        return larger[0]
    law = GROWN_FROM.get(model.law)
    if law is None:
        return None
    smaller = MeasurementModel(law, model.stroke_mm)
    if model.priors is None:
        return smaller
    return MeasurementModel(law, model.stroke_mm,
                            tuple(p for p in model.priors if p[0] in smaller.param_names))


def held_of(model: MeasurementModel, fix: Mapping | None,
             models: Sequence[MeasurementModel]) -> dict:
    """``fix`` without the parameters that ``model`` lacks and another law of ``models`` has:
    a held value applies to the laws that have the parameter (a name no law has stays, to
    be reported)."""
    known = {n for m in models for n in m.param_names}
    return {n: v for n, v in (fix or {}).items() if n in model.param_names or n not in known}



#: A fitted static peak this many standard errors above zero rules out the laws without one
#: for that item, whatever their BIC: the BIC's AR(1) deviance scores the residuals'
#: innovations, and a missing peak is a smooth misfit that a lag-1 coefficient near 1
#: absorbs.
PEAK_Z = 3.0


def peak_measured(models: list[MeasurementModel], fits: list[FitResult],
                   rows: list[np.ndarray], n: int) -> np.ndarray:
    """Per item (of ``n``), whether a fitted ``f_static_excess`` (one fit of each law in
    ``fits``, of the items ``rows``) stands :data:`PEAK_Z` stderr above zero; a peak on
    its bound (no width: stderr 0) does not stand."""
    peak = np.zeros(n, bool)
    for m, r, at in zip(models, fits, rows, strict=True):
        if "f_static_excess" in m.param_names and r.n_trials:
            value, stderr = (np.asarray(r.values["f_static_excess"]),
                             np.asarray(r.stderr["f_static_excess"]))
            peak[at] |= (stderr > 0) & (value > PEAK_Z * stderr)
    return peak


def choice(models: list[MeasurementModel], fits: list[FitResult], rows: list[np.ndarray]
            ) -> tuple[np.ndarray, pd.DataFrame]:
    """Per item, the index of the first law whose BIC is within ``BIC_TIE`` of the best (one
    fit of each law in ``fits``, of the items ``rows``), a law without a static peak only
    where no law's peak stands (:func:`peak_measured`); and the BIC table (NaN where a
    law was not fitted)."""
    n = max(at.max(initial=-1) for at in rows) + 1
    bic = pd.DataFrame({m.name: np.full(n, np.nan) for m in models})
    for m, r, at in zip(models, fits, rows, strict=True):
        bic.loc[at, m.name] = r.bic
    peak = peak_measured(models, fits, rows, n)
    eligible = bic.copy()
    for m in models:
        if "f_static_excess" not in m.param_names:
            eligible.loc[peak, m.name] = np.nan
    return np.array([list(bic.columns).index(name) for name in choose(eligible)]), bic


def by_bic(models: list[MeasurementModel], fits: list[FitResult],
            rows: list[np.ndarray] | None = None) -> tuple[FitResult, np.ndarray, pd.DataFrame]:
    """Per item, the fit of the law :func:`choice` picks (``rows``: the items each fit is
    of; default all); the law's index per item; the BIC table."""
    rows = rows or [np.arange(fits[0].n_trials)] * len(fits)
    chosen, bic = choice(models, fits, rows)
    where = [np.searchsorted(at, np.flatnonzero(chosen == j)) for j, at in enumerate(rows)]
    return (in_order([take_trials(r, w) for r, w in zip(fits, where, strict=True)], chosen),
            chosen, bic)


def from_optimum(model: MeasurementModel, items: Sequence[MeasurementData], other: FitResult
                  ) -> np.ndarray:
    """Starting points of ``model``: another law's optimum where it has the parameter, the
    data's guess elsewhere, a damping where it acts (:data:`DAMPING_START`), a static excess
    dropped into the kinetic level by its mean share (:func:`_mean_weakening`);
    unconstrained."""
    starts = []
    for i, d in enumerate(items):
        v = other.params(i)
        start = d.guess | v
        if "damping" in model.param_names and "damping" not in v:
            start["damping"] = DAMPING_START * v["f_kin"] * v["ramp"] / model.stroke_mm
        if "f_static_excess" in v and "f_static_excess" not in model.param_names:
            start["f_kin"] = v["f_kin"] + v["f_static_excess"] * _mean_weakening(
                v["slip_length"], model.stroke_mm)
        starts.append(to_unconstrained(model, start))
    return np.stack(starts)


def _mean_weakening(slip_length, stroke_mm: float):
    """Mean of ``exp(-s / slip_length)`` over a stroke's slip ``s`` in ``[0, stroke_mm]``:
    the share of the static excess a law without it carries in its kinetic level."""
    ratio = stroke_mm / slip_length
    return -np.expm1(-ratio) / ratio


def in_order(parts: list[FitResult], chosen: np.ndarray) -> FitResult:
    """One result, rows in item order, from per-law results of the rows that chose each law."""
    parts = [p for p in parts if p.n_trials]
    rows = np.concatenate([np.flatnonzero(chosen == j) for j in np.unique(chosen)])
    return take_trials(concat_results(parts), np.argsort(rows))


