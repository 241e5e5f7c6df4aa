"""The per-trial result table of a batch of fits, and its lmfit-style report."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from frictionfit.errors import FitError, Status
from frictionfit.models import PARAMS

__all__ = ["FitResult", "concat_results", "fit_report", "param_table", "take_trials"]


@dataclass
class FitResult:
    """Per-trial fit results, one row per trial; values in physical units.

    Attributes
    ----------
    model : list of str
        The model fitted (or chosen, with ``model="auto"``) per trial.
    values, stderr : DataFrame
        Physical parameter values and standard errors (unit: ``PARAMS[name].unit``), one
        row per trial and one column per parameter of any trial's model (in the order
        they first appear): ``values["k"]`` is a column, ``values.loc[i]`` a row. NaN where
        a trial's model has no such parameter, where a trial has no fit (too little data),
        and in ``stderr`` where the covariance could not be computed (such parameters are
        flagged). :meth:`params` and :meth:`stderrs` give one trial's own parameters.
    flags : list of dict
        Per parameter, a short reason it is not identifiable ("at bound",
        "stderr > value", "singular", "trades off with <name>") or that it was not
        fitted ("fixed", "tied"); absent when it is fine.
    status : ndarray of Status codes
    chi2, redchi, aic, bic, r2, cond : ndarray
    n_steps : ndarray
        Solver steps used.
    ndata, nvarys : ndarray, optional
        Per trial, the data points fitted (samples, or blocks of a whole measurement; those
        masked out not counted) and the parameters varied (lmfit's names).
    bic_table : DataFrame or None
        With ``model="auto"``: BIC per trial (rows) and family member (columns).
    wall_s : float
        Wall time of the whole batch, s.
    solver : str
        The solver used; ``n_starts`` the number of starting points per trial.
    direction, drive_input, drive, stroke_mm, priors
        What :meth:`predict` needs to recompute a trial's fitted curve, and the ``priors=``
        the fit was given (``None``: the parameters' defaults).
    init : list of dict, optional
        Per trial, the starting point in physical units (the data-driven guess).
    correl : list of dict, optional
        Per trial, ``(name_a, name_b) -> correlation`` of the free parameters' estimates.
    derived : list of dict, optional
        Per trial, ``name -> (value, stderr)`` of quantities derived from the fit (whole
        measurements: :data:`frictionfit.fit.derived.DERIVED`, with their units).
    cov : list of ndarray, optional
        Per trial, the covariance of the free parameters' estimates in the fit's
        unconstrained coordinates (rows in the order of :meth:`free_names`; scaled by the
        reduced chi-square as lmfit's ``covar``; NaN where it could not be computed).
    session_rigs : dict, optional
        Whole fits with the session's motor profile held: session -> the
        :class:`~frictionfit.fit.session.SessionRig` held (``None`` otherwise).
    """

    model: list[str]
    values: pd.DataFrame
    stderr: pd.DataFrame
    flags: list[dict]
    status: np.ndarray
    chi2: np.ndarray
    redchi: np.ndarray
    aic: np.ndarray
    bic: np.ndarray
    r2: np.ndarray
    cond: np.ndarray
    n_steps: np.ndarray
    u: list[np.ndarray] = field(repr=False)
    bic_table: pd.DataFrame | None = None
    wall_s: float = 0.0
    solver: str = "lm"
    n_starts: int = 1
    direction: np.ndarray | None = field(default=None, repr=False)
    drive_input: object = field(default=None, repr=False)
    drive: str = "events"
    stroke_mm: float = 1.0
    priors: dict | None = None
    init: list[dict] | None = field(default=None, repr=False)
    correl: list[dict] | None = field(default=None, repr=False)
    derived: list[dict] | None = field(default=None, repr=False)
    cov: list[np.ndarray] | None = field(default=None, repr=False)
    ndata: np.ndarray | None = field(default=None, repr=False)
    nvarys: np.ndarray | None = field(default=None, repr=False)
    session_rigs: dict | None = field(default=None, repr=False)

    def __repr__(self) -> str:
        from collections import Counter

        models = dict(Counter(self.model))
        status = {Status(int(k)).name.lower(): n for k, n in Counter(self.status.tolist()).items()}
        return (f"FitResult({self.n_trials} trials, models {models}, status {status}, "
                f"solver {self.solver!r}, {self.wall_s:.2f} s)")

    @property
    def n_trials(self) -> int:
        return len(self.model)

    def params(self, i: int) -> dict[str, float]:
        """Trial ``i``'s own parameters (its model's, in their order), name -> value in
        physical units (``PARAMS[name].unit``)."""
        return _own(self.values, i, self.member(i).param_names)

    def stderrs(self, i: int) -> dict[str, float]:
        """Trial ``i``'s own parameters' standard errors (its model's, in their order),
        name -> stderr in physical units (``PARAMS[name].unit``)."""
        return _own(self.stderr, i, self.member(i).param_names)

    def unit(self, i: int, name: str) -> tuple[str, float]:
        """Parameter ``name``'s unit in trial ``i``'s tables and report, and the factor from
        its value in :attr:`values` to that unit (here ``PARAMS[name].unit`` and 1)."""
        return PARAMS[name].unit, 1.0

    def free_names(self, i: int) -> list[str]:
        """The parameters trial ``i``'s fit varied (the rows of ``cov[i]``)."""
        return [n for n in self.member(i).param_names
                if self.flags[i].get(n) not in ("fixed", "tied")]

    def to_frame(self, ids=None) -> pd.DataFrame:
        """One row per trial: id, model, status, each parameter with stderr and unit, stats."""
        from frictionfit.fit.derived import DERIVED  # it imports the fitter: not at the top

        names = {m: self.member(self.model.index(m)).param_names  # one lookup per model
                 for m in dict.fromkeys(self.model)}
        rows = []
        for i in range(self.n_trials):
            row = {"trial": i if ids is None else ids[i], "model": self.model[i],
                   "status": Status(int(self.status[i])).name.lower()}
            own = names[self.model[i]]
            values, stderr = _own(self.values, i, own), _own(self.stderr, i, own)
            for name, v in values.items():
                unit, scale = self.unit(i, name)
                row[f"{name} [{unit}]"] = v * scale
                row[f"{name}_stderr [{unit}]"] = stderr[name] * scale
                row[f"{name}_flag"] = self.flags[i].get(name, "")
            for name, (v, se) in (self.derived[i] if self.derived is not None else {}).items():
                row[f"{name} [{DERIVED[name]}]"] = v
                row[f"{name}_stderr [{DERIVED[name]}]"] = se
            for stat in ("chi2", "redchi", "aic", "bic", "r2", "cond", "n_steps", "ndata",
                         "nvarys"):
                if getattr(self, stat) is not None:
                    row[stat] = getattr(self, stat)[i]
            row["wall_s_per_trial"] = self.wall_s / max(self.n_trials, 1)
            rows.append(row)
        return pd.DataFrame(rows)

    def predict(self, i: int, t) -> np.ndarray:
        """The fitted force (N) of trial ``i`` at uniform times ``t`` (s)."""
        import jax.numpy as jnp

        if self.direction is None or self.drive_input is None:
            raise ValueError("this FitResult does not carry its drive; refit with fit_trials")
        member = self.member(i)
        if self.drive == "events":
            drive_i = (self.drive_input[0][i], self.drive_input[1][i])
        else:
            drive_i = jnp.asarray(self.drive_input[i])
        return np.asarray(member.predict(jnp.asarray(self.u[i]), jnp.asarray(t), drive_i,
                                         self.direction[i]))

    @staticmethod
    def sample_mask(y) -> np.ndarray:
        """The samples a fit of ``y (n_trials, n_samples)`` uses: finite, and not in a run
        at a clipping extreme (:func:`~frictionfit.fit._guess.saturated_samples`)."""
        from frictionfit.fit._guess import saturated_samples

        y = np.atleast_2d(np.asarray(y, dtype=np.float64))
        return np.isfinite(y) & ~saturated_samples(y)

    def member(self, i: int):
        """Trial ``i``'s :class:`~frictionfit.models.ContactModel` (with drive and priors)."""
        from frictionfit.models import get_model

        return get_model(self.model[i], drive=self.drive, stroke_mm=self.stroke_mm,
                         priors=self.priors)


def fit_report(result: FitResult, i: int = 0, min_correl: float = 0.1) -> str:
    """An lmfit-style report of trial ``i``: statistics, values +/- stderr (%) with the
    starting value, flags, and the correlations above ``min_correl`` in size."""
    lines = [
        f"[[Model]]\n    {result.model[i]}",
        "[[Fit Statistics]]",
        f"    status             = {Status(int(result.status[i])).name}"
        f" ({Status(int(result.status[i])).message})",
        f"    solver steps       = {result.n_steps[i]}",
        *([f"    # data points      = {result.ndata[i]}", f"    # variables        = "
           f"{result.nvarys[i]}"] if result.ndata is not None else []),
        f"    chi-square         = {result.chi2[i]:.6g}",
        f"    reduced chi-square = {result.redchi[i]:.6g}",
        f"    Akaike info crit   = {result.aic[i]:.6g}",
        f"    Bayesian info crit = {result.bic[i]:.6g}",
        f"    R-squared          = {result.r2[i]:.6g}",
        f"    condition number   = {result.cond[i]:.3g}",
        "[[Variables]]",
    ]
    stderr = result.stderrs(i)
    for name, v in result.params(i).items():
        unit, scale = result.unit(i, name)
        v, se = v * scale, stderr[name] * scale
        pct = f" ({100 * se / abs(v):.2f}%)" if np.isfinite(se) and v != 0 else ""
        flag = result.flags[i].get(name)
        warn = (f"  ({flag})" if flag in ("fixed", "tied")
                else f"  <-- not identifiable: {flag}" if flag else "")
        init = f" (init = {result.init[i][name] * scale:.6g})" if result.init is not None else ""
        lines.append(f"    {name:16s} = {v:.6g} +/- {se:.3g}{pct} {unit}{init}{warn}")
    if result.derived is not None:
        lines.append("[[Derived]]")
        from frictionfit.fit.derived import DERIVED

        for name, (v, se) in result.derived[i].items():
            lines.append(f"    {name:16s} = {v:.6g} +/- {se:.3g} {DERIVED.get(name, '')}")
    if result.correl is not None:
        pairs = sorted(((a, b, r) for (a, b), r in result.correl[i].items()
                        if np.isfinite(r) and abs(r) >= min_correl), key=lambda x: -abs(x[2]))
        if pairs:
            lines.append(f"[[Correlations]] (unreported correlations are < {min_correl:.3f})")
            lines += [f"    C({a}, {b}) = {r:+.4f}" for a, b, r in pairs]
    priors = result.member(i).prior_table
    if priors:
        lines.append("[[Priors]] (Normal on the log of loglogit parameters; the fit is MAP)")
        for name, (centre, sd) in priors.items():
            logged = PARAMS[name].transform == "loglogit"
            unit, scale = result.unit(i, name)
            kind, sd_of = ("median", "log sd") if logged else ("mean", "sd")
            sd = sd if logged else sd * scale  # the sd of a log is free of the unit
            lines.append(f"    {name:16s} {kind} {centre * scale:.6g} {unit}, {sd_of} {sd:.3g}")
    if result.bic_table is not None:
        lines.append("[[BIC by model]]")
        for name, b in result.bic_table.iloc[i].items():
            mark = "  <-- chosen" if name == result.model[i] else ""
            shown = f"{b:.6g}" if np.isfinite(b) else "none (not fitted, or no finite fit)"
            lines.append(f"    {name:16s} {shown}{mark}")
    return "\n".join(lines)


def param_table(rows: Sequence[Mapping[str, float]]) -> pd.DataFrame:
    """Per-trial ``name -> value`` dicts as :attr:`FitResult.values` holds them: one row per
    trial, one float64 column per parameter (in the order they first appear), NaN where a
    trial has no such parameter."""
    return pd.DataFrame(list(rows), index=pd.RangeIndex(len(rows)), dtype=np.float64)


def _own(table: pd.DataFrame, i: int, names: Sequence[str]) -> dict[str, float]:
    """Row ``i`` of a per-parameter table, as ``name -> value`` over ``names``."""
    row = table.iloc[i]
    return {n: float(row[n]) for n in names}


def _concat(values: list, name: str):
    """Per-trial fields are concatenated; per-batch settings must agree across chunks."""
    first = values[0]
    if isinstance(first, np.ndarray):
        return np.concatenate(values)
    if isinstance(first, pd.DataFrame):
        return pd.concat(values, ignore_index=True)
    if isinstance(first, list):
        return [row for part in values for row in part]
    if isinstance(first, tuple):  # e.g. (t_out, t_back) per trial
        return tuple(_concat(list(items), name) for items in zip(*values, strict=True))
    if all(v == first for v in values):  # None, solver name, stroke, ...
        return first
    raise FitError(f"parts disagree on the per-batch result field {name!r}: {values}")


def concat_results(parts: Sequence, wall_s: float | None = None):
    """One result from per-chunk results (``FitResult``, ``Posterior``), rows in order.

    Per-trial fields (arrays, lists, tables) are concatenated and per-batch
    settings (solver, drive, ...) carried over; ``wall_s`` is the given wall time
    of the whole call (s), or the sum over the chunks.
    """
    cls = type(parts[0])
    merged = {f.name: _concat([getattr(p, f.name) for p in parts], f.name)
              for f in dataclasses.fields(cls) if f.init and f.name != "wall_s"}
    merged["wall_s"] = sum(p.wall_s for p in parts) if wall_s is None else wall_s
    return cls(**merged)


def _take(value, rows: np.ndarray, n_trials: int):
    """Rows of a per-trial field (array, list, table, tuple of them); other values unchanged."""
    if isinstance(value, np.ndarray) and value.ndim and value.shape[0] == n_trials:
        return value[rows]
    if isinstance(value, list) and len(value) == n_trials:
        return [value[i] for i in rows]
    if isinstance(value, pd.DataFrame) and len(value) == n_trials:
        return value.iloc[rows].reset_index(drop=True)
    if isinstance(value, tuple):
        return tuple(_take(v, rows, n_trials) for v in value)
    return value


def take_trials(result, rows):
    """The trials ``rows`` (indices or a slice) of a result (``FitResult``, ``Posterior``);
    ``concat_results`` undone.

    ``wall_s`` is shared out in proportion to the trials kept.
    """
    n = result.n_trials
    idx = np.arange(n)[rows] if isinstance(rows, slice) else np.asarray(rows, dtype=int)
    kept = {f.name: _take(getattr(result, f.name), idx, n)
            for f in dataclasses.fields(result) if f.init}
    kept["wall_s"] = result.wall_s * idx.size / max(n, 1)
    return type(result)(**kept)
