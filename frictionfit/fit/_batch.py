"""``fit_trials``: fit a family member (or the whole family, ``model="auto"``) to a batch."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import jax
import numpy as np
import optimistix as optx
import pandas as pd
from tqdm.auto import tqdm

from frictionfit.errors import FitError, Status
from frictionfit.fit._guess import initial_guess, multi_starts, saturated_samples, trial_keys
from frictionfit.fit._numerics import map_chunks
from frictionfit.fit._optx import solve_pooled
from frictionfit.fit._problem import Problem, jacobian_fn, residual_fn
from frictionfit.fit._solver_choice import SolverSettings, solver_settings
from frictionfit.fit._stats import choose, flag_fast_loading, statistics, status_of
from frictionfit.fit.result import FitResult, param_table
from frictionfit.fit.trials import Trials, as_trials
from frictionfit.models import FAMILY, PARAMS, get_model

__all__ = ["fit_trials"]

#: Fewest trials for which a fit shows a progress bar (on a terminal).
PROGRESS_MIN_TRIALS = 64


def _at_optimum(model, free, u, data, chunk):
    """Masked residuals and ``J^T J`` (free parameters) at ``u``, in padded chunks."""
    return map_chunks(jacobian_fn(model, free), (u[:, list(free)], data), chunk)


@dataclass(frozen=True, eq=False)
class Batch:
    """What every member's fit shares, built once per batch: the trials, their sample
    interval ``dt`` (s), which ones have a clipped run, their keys (:func:`trial_keys`)
    and noise sd (N)."""

    trials: Trials
    dt: float
    saturated: np.ndarray
    keys: np.ndarray
    noise: np.ndarray

    def problem(self, base: np.ndarray) -> Problem:
        """The least-squares problem of every trial from unconstrained ``base``."""
        return Problem.of(self.trials, base, self.noise)


@dataclass(frozen=True)
class MemberSettings:
    """What a member's fit holds fixed (physical values) or tied, and its starts."""

    drive: str
    stroke_mm: float
    priors: Mapping | None
    n_starts: int
    seed: int
    fixed: Mapping[str, float] = field(default_factory=dict)
    tied: tuple[str, ...] = ()


def _solve(model, free, starts, data, solve: SolverSettings):
    """Run the chosen solver from every start; keep each trial's lowest-cost optimum."""
    n_starts, n, _ = starts.shape
    u_all = starts.reshape(n_starts * n, -1)
    data_all = jax.tree_util.tree_map(lambda a: np.concatenate([a] * n_starts), data)
    cols = list(free)
    # a bar on a terminal only, for batches long enough to wait for
    with tqdm(total=len(u_all), desc=f"fitting {model.name}", unit="trial", leave=False,
              disable=None if len(u_all) >= PROGRESS_MIN_TRIALS else True) as bar:
        u_free, code, steps = solve_pooled(
            solve.solver, residual_fn(model, free), u_all[:, cols], data_all,
            pool_size=solve.chunk_size, max_steps=solve.max_steps, segment=solve.segment,
            threads=solve.threads, progress=bar.update)
    nonfinite = code == Status.NONFINITE
    u_all = u_all.copy()
    u_all[:, cols] = u_free
    resid, jtj = _at_optimum(model, free, u_all, data_all, solve.chunk_size)
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is NONFINITE, not a crash
        cost = np.where(nonfinite, np.inf, np.nan_to_num(np.sum(resid**2, axis=1), nan=np.inf))
    best = np.argmin(cost.reshape(n_starts, n), axis=0) * n + np.arange(n)
    return (u_all[best], code[best], nonfinite[best], steps.reshape(n_starts, n).sum(0),
            resid[best], jtj[best])


def _status(solver_status: int, status: Status) -> Status:
    """A trial's status: ``status`` from its statistics, except that a fit the solver
    stopped short of convergence for another reason than its step budget
    (``ILL_CONDITIONED``: a singular linear solve) keeps the solver's reason."""
    return Status(solver_status) if status == Status.MAX_STEPS else status


def _starts(model, base, free, batch: Batch, how: MemberSettings, extra_starts):
    """Starting points ``(k, n_trials, n_params)``: the data-driven ones, then ``extra_starts``
    with the held parameters at their ``base`` values."""
    starts = multi_starts(model, base, how.n_starts, how.seed, keys=batch.keys)
    if extra_starts is None:
        return starts
    extra = np.array(extra_starts, dtype=np.float64)
    held = [j for j in range(model.n_params) if j not in free]
    extra[:, :, held] = base[None][:, :, held]
    return np.concatenate([starts, extra])


def _fit_member(model, batch: Batch, u_start, how: MemberSettings, solve: SolverSettings,
                extra_starts=None):
    """Fit one member: multi-start solve, statistics; returns a dict of per-trial arrays.

    ``extra_starts`` (k, n_trials, n_params): further starting points (e.g. the
    smaller family member's optimum), tried besides the data-driven ones.
    """
    names, t_mask = model.param_names, batch.trials.mask
    free = tuple(j for j, n in enumerate(names) if n not in how.fixed)
    base = u_start.copy()
    for name, value in how.fixed.items():
        if name in names:
            base[:, names.index(name)] = PARAMS[name].to_unconstrained(value)
    starts = _starts(model, base, free, batch, how, extra_starts)
    u, code, nonfinite, steps, resid, jtj = _solve(
        model, free, starts, batch.problem(base), solve)
    stats = statistics(model, u, resid, jtj, t_mask, free,
                       [n for n in how.fixed if n in names and n not in how.tied])
    if how.drive == "events":
        flag_fast_loading(stats["flags"], stats["values"], batch.dt, how.stroke_mm)
    status = np.array([
        Status.NONFINITE if nonfinite[i] and t_mask[i].sum() >= 3 * len(free)
        else _status(code[i], status_of(len(free), code[i] == Status.CONVERGED, u[i],
                                        stats["chi2"][i], stats["cond"][i], t_mask[i],
                                        saturated=batch.saturated[i],
                                        flags=stats["flags"][i]))
        for i in range(u.shape[0])], dtype=np.int64)
    for i in np.flatnonzero(status == Status.INSUFFICIENT_DATA):  # no fit: no numbers
        stats["values"][i] = {k: np.nan for k in stats["values"][i]}
        stats["stderr"][i] = {k: np.nan for k in stats["stderr"][i]}
    return dict(stats, u=u, steps=steps, status=status, free=free)


def _tie(fit, model, tie, groups):
    """Per group, the inverse-variance mean of each tied parameter (physical) and its stderr."""
    values, errs = {}, {}
    for name in tie:
        if name not in model.param_names:
            continue
        v = np.array([row[name] for row in fit["values"]])
        se = np.array([row[name] for row in fit["stderr"]])
        w = np.where(np.isfinite(se) & (se > 0) & (fit["status"] == Status.CONVERGED),
                     1.0 / np.maximum(se, 1e-300) ** 2, 0.0)
        mean, err = np.empty_like(v), np.full_like(v, np.nan)
        for g in np.unique(groups):
            sel = groups == g
            ws = w[sel].sum()
            mean[sel] = (w[sel] @ v[sel]) / ws if ws > 0 else np.median(v[sel])
            err[sel] = 1.0 / np.sqrt(ws) if ws > 0 else np.nan
        values[name], errs[name] = mean, err
    return values, errs


def fit_trials(
    y, t=None, drive_input=None, *, model: str = "auto", direction=None, drive: str = "events",
    solver: str | optx.AbstractLeastSquaresSolver = "lm", max_steps: int = 100,
    steps_per_round: int = 4, chunk_size: int = 32, rtol: float | None = None,
    atol: float | None = None, ftol: float | None = None, u0=None, n_starts: int = 1, seed: int = 0,
    threads: int | None = None, fix: Mapping[str, float] | None = None, tie: Sequence[str] = (),
    groups=None, stroke_mm: float = 1.0,
    priors: Mapping[str, tuple[float, float] | None] | None = None,
) -> FitResult:
    """Fit a contact model to every trial of a batch.

    Parameters
    ----------
    y : array (n_trials, n_samples), or Trials
        Force of one channel per trial, N; NaN marks missing samples (masked out). Or a
        :class:`~frictionfit.fit.Trials`, which brings ``t``, ``drive_input``, ``drive``
        and ``direction`` (then not given).
    t : array (n_samples,)
        Uniform sample times, s (shared by the batch).
    drive_input : tuple or array
        ``(t_out, t_back)``: command times, s (scalars or per trial), ``drive="events"``;
        or the displacement, mm ``(n_trials, n_samples)``, ``drive="given"``.
    model : str, default "auto"
        A family member, or ``"auto"``: fit all, keep the smallest within ``BIC_TIE`` of the best.
    direction : array (n_trials,), optional
        +1/-1 per trial; estimated from the out stroke when omitted.
    solver : {"lm", "optx-lm", "dogleg", "gauss-newton"} or an optimistix least-squares solver
        ``"lm"``: :class:`BatchedLevenbergMarquardt` (the fastest); the others optimistix's
        ``LevenbergMarquardt``, ``Dogleg``, ``GaussNewton``; all in the same refilled pools.
    max_steps, steps_per_round, chunk_size : int
        Steps per trial; steps per compiled call, between refills; slots per pool (32).
    rtol, atol, ftol : float, optional
        A named solver's step tolerances (``rtol``: the LM's ``xtol``; ``atol``: optimistix's)
        and relative cost decrease (``ftol``); default ``DATA_RTOL``, ``DATA_ATOL``,
        ``DATA_FTOL``. A solver object brings its own (FitError beside one).
    u0 : array (n_trials, n_params), optional
        Unconstrained starting points (one named model only).
    n_starts, seed : int
        The guess plus ``n_starts - 1`` jitters seeded by each trial's own samples (results
        do not depend on the batch); the lowest-cost optimum is kept.
    fix : mapping name -> physical value, optional
        Parameters held at a known value (flagged "fixed", stderr 0).
    tie, groups : sequence of str, array (n_trials,)
        Parameters shared by a group's trials: after a free fit each is fixed at its
        group's inverse-variance mean (reported with its combined stderr, flagged
        "tied") and the rest refitted.
    stroke_mm : float
        The rig's finger stroke (mm) for ``drive="events"``; stiffness is per mm of it.
    priors : mapping name -> (centre, sd) or None, optional
        Normal priors on sampling coordinates (``loglogit``: median in its unit, sd of
        the log) updating the defaults (``RAMP_PRIOR``, ``SLIP_PRIOR``); ``None``: flat.
        The fit is then the MAP estimate; chi-square, AIC and BIC are of the data.
    threads : int, optional
        Host threads, a pool each (default: the cores this process may use; results do
        not depend on it, bit for bit). ``"lm"`` only: the optimistix solvers' batched QR
        (jaxlib's LAPACK kernel) is not safe in two threads at once.

    Returns
    -------
    FitResult
        A row and a Status per trial (a failed trial never sinks the batch; clipped: SATURATED).

    Examples
    --------
    >>> from frictionfit.simulation.trials import simulate_trials
    >>> ts = simulate_trials("stick_slip", 2, seed=0)
    >>> res = fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model="stick_slip")
    >>> [Status(s).name for s in res.status]
    ['CONVERGED', 'CONVERGED']
    """
    start = time.perf_counter()
    trials = as_trials(y, t, drive_input, drive=drive, direction=direction)
    solve = solver_settings(solver, rtol, atol, ftol, max_steps, steps_per_round, chunk_size,
                            threads)
    how = _member_settings(trials.drive, stroke_mm, priors, n_starts, seed, fix, tie, groups)
    batch = _prepare(trials)
    members = _members(model, how)
    fits, inits = _fit_family(members, batch, solve, how, None if model == "auto" else u0,
                              tie, groups)
    return _assemble(fits, inits, batch, how, solve.name, model == "auto", start)


def _member_settings(drive, stroke_mm, priors, n_starts, seed, fix, tie,
                     groups) -> MemberSettings:
    """The settings of every member's fit; unknown fixed or tied names are refused."""
    fix = dict(fix or {})
    unknown = [n for n in [*fix, *tie] if n not in PARAMS]
    if unknown:
        raise FitError(f"cannot fix or tie unknown parameter(s) {unknown}; "
                       f"parameters are {list(PARAMS)}")
    if tie and groups is None:
        raise FitError("tie needs groups: one group label per trial (e.g. the measurement id)")
    return MemberSettings(drive=drive, stroke_mm=stroke_mm, priors=priors,
                          n_starts=max(int(n_starts), 1), seed=seed, fixed=fix)


def _prepare(trials: Trials) -> Batch:
    """What every member's fit shares: sample interval, clipped trials, keys, noise scale."""
    # Samples held at a clipping extreme are censored, not measured: left out (SATURATED).
    return Batch(trials=trials, dt=trials.dt,
                 saturated=saturated_samples(trials.y).any(axis=1), keys=trial_keys(trials.y),
                 noise=Problem.noise_of(trials))


def _members(model: str, how: MemberSettings) -> list:
    """The family members to fit: all of them for ``"auto"``, else the one named."""
    names = [m.name for m in FAMILY] if model == "auto" else [model]
    try:
        return [get_model(n, drive=how.drive, stroke_mm=how.stroke_mm, priors=how.priors)
                for n in names]
    except ValueError as exc:
        raise FitError(str(exc)) from None


def _fit_family(members, batch: Batch, solve: SolverSettings, how: MemberSettings, u0, tie,
                groups):
    """Every member's fit (``{name: per-trial dict}``) and starting points (physical)."""
    fits, inits, previous = {}, {}, None
    for member in members:
        start_u = np.array(u0 if u0 is not None else initial_guess(
            member, batch.trials.t, batch.trials.y, *batch.trials.guess_times,
            batch.trials.direction), dtype=np.float64)
        inits[member.name] = [{k: float(v) for k, v in row.items()}
                              for row in _rows_of(member.physical(start_u))]
        fit = _fit_member(member, batch, start_u, how, solve,
                          _warm_start(member, start_u, previous))
        if tie:
            fit = _refit_tied(fit, member, batch, how, solve, tie, np.asarray(groups))
        fits[member.name] = fit
        previous = (member, fit["u"])
    if not tie:  # with one member there is no smaller one to revisit
        _backward_pass(fits, members, batch, how, solve)
    return fits, inits


def _refit_tied(fit, member, batch: Batch, how: MemberSettings, solve: SolverSettings, tie,
                groups):
    """The fit refitted with each tied parameter at its group's inverse-variance mean."""
    means, errs = _tie(fit, member, tie, groups)
    refit = _fit_member(member, batch, fit["u"],
                        replace(how, fixed={**how.fixed, **means}, tied=tuple(means)), solve)
    for i in range(batch.trials.n_trials):
        for name in means:
            refit["stderr"][i][name] = float(errs[name][i])
        # Holding a tied parameter at its group mean hides the trade-offs it had:
        # what the free fit could not identify stays flagged.
        for name, flag in fit["flags"][i].items():
            refit["flags"][i].setdefault(name, flag)
    return refit


def _backward_pass(fits, members, batch: Batch, how: MemberSettings, solve: SolverSettings):
    """Refit each smaller member (in place) also from the next bigger one's optimum.

    Extra effects dropped, so a smaller member stuck in a poor local minimum is not
    out-scored by a bigger one that found the right basin.
    """
    for small, big in reversed(list(zip(members[:-1], members[1:], strict=True))):
        back = _warm_start(small, fits[small.name]["u"], (big, fits[big.name]["u"]))
        fits[small.name] = _fit_member(small, batch, fits[small.name]["u"], how, solve, back)


def _assemble(fits, inits, batch: Batch, how: MemberSettings, solver: str, auto: bool,
              start: float) -> FitResult:
    """Per trial, the member the BIC chooses, with its statistics, as a FitResult."""
    bic = pd.DataFrame({n: fit["bic"] for n, fit in fits.items()})
    chosen = choose(bic)
    rows = [fits[name] for name in chosen]
    with np.errstate(over="ignore", invalid="ignore"):
        total_ss = np.array([np.sum((yi[m] - yi[m].mean()) ** 2) if m.any() else np.nan
                             for yi, m in zip(batch.trials.y, batch.trials.mask, strict=True)])
        chi2 = np.array([r["chi2"][i] for i, r in enumerate(rows)])
        # A constant (dead) channel has no variance to explain: R^2 is undefined (NaN).
        r2 = 1.0 - np.divide(chi2, total_ss, out=np.full_like(chi2, np.nan),
                             where=total_ss > 0)
    pick = {k: np.array([r[k][i] for i, r in enumerate(rows)])
            for k in ("chi2", "redchi", "aic", "bic", "cond", "steps", "status", "ndata",
                      "nvarys")}
    per_trial = {k: [r[k][i] for i, r in enumerate(rows)]
                 for k in ("flags", "u", "correl", "cov")}
    tables = {k: param_table([r[k][i] for i, r in enumerate(rows)]) for k in ("values", "stderr")}
    return FitResult(
        model=list(chosen), status=pick["status"], chi2=pick["chi2"], redchi=pick["redchi"],
        aic=pick["aic"], bic=pick["bic"], r2=r2, cond=pick["cond"], n_steps=pick["steps"],
        ndata=pick["ndata"], nvarys=pick["nvarys"],
        init=[inits[name][i] for i, name in enumerate(chosen)], **per_trial, **tables,
        bic_table=bic if auto else None, wall_s=time.perf_counter() - start,
        solver=solver, n_starts=how.n_starts, direction=batch.trials.direction,
        drive_input=batch.trials.drive_input, drive=how.drive, stroke_mm=how.stroke_mm,
        priors=dict(how.priors) if how.priors is not None else None,
    )


def _rows_of(columns: dict) -> list[dict]:
    """``{name: array (n,)}`` -> one ``{name: value}`` per trial."""
    names = list(columns)
    return [dict(zip(names, vals, strict=True))
            for vals in zip(*(np.asarray(columns[n]) for n in names), strict=True)]


def _warm_start(member, start_u, previous):
    """``(1, n, p)``: the smaller member's optimum for the shared parameters, else ``None``.

    With ``model="auto"`` each member also starts where the smaller one ended, so a
    bigger member fits at least about as well and the BIC compares nested optima.
    """
    if previous is None:
        return None
    small, u_small = previous
    warm = start_u.copy()
    for j, name in enumerate(member.param_names):
        if name in small.param_names:
            warm[:, j] = u_small[:, small.param_names.index(name)]
    return warm[None]
