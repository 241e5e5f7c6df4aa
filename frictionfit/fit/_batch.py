"""``fit_trials``: fit a family member (or the whole family, ``model="auto"``) to a batch."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence

import jax
import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from frictionfit._system import available_cores
from frictionfit.errors import FitError, Status
from frictionfit.fit._guess import (
    direction_of,
    initial_guess,
    multi_starts,
    saturated_samples,
    trial_keys,
)
from frictionfit.fit._lm import CONVERGED, NONFINITE, LMConfig, solve_pool
from frictionfit.fit._numerics import pad_rows
from frictionfit.fit._optx import OPTX_SOLVERS, solve_rounds
from frictionfit.fit._problem import jacobian_fn, noise_scale, normal_fn
from frictionfit.fit._stats import choose, flag_fast_loading, statistics, status_of
from frictionfit.fit.result import FitResult
from frictionfit.fit.solver import BatchedLevenbergMarquardt
from frictionfit.models import FAMILY, PARAMS, get_model

__all__ = ["SOLVERS", "fit_trials"]

SOLVERS = ("lm", *OPTX_SOLVERS)
#: Fewest trials for which a fit shows a progress bar (on a terminal).
PROGRESS_MIN_TRIALS = 64


def _at_optimum(model, free, u, data, chunk):
    """Masked residuals and ``J^T J`` (free parameters) at ``u``, in padded chunks."""
    fn = jacobian_fn(model, free)
    n = u.shape[0]
    resid, jtj = [], []
    for start in range(0, n, chunk):
        idx = np.arange(start, min(start + chunk, n))
        rows = pad_rows(idx, chunk)
        r, a = fn(u[rows][:, list(free)], jax.tree_util.tree_map(lambda x, r=rows: x[r], data))
        resid.append(np.asarray(r)[: idx.size])
        jtj.append(np.asarray(a)[: idx.size])
    return np.concatenate(resid), np.concatenate(jtj)


def _solve(model, free, starts, data, opts):
    """Run the chosen solver from every start; keep each trial's lowest-cost optimum."""
    n_starts, n, _ = starts.shape
    u_all = starts.reshape(n_starts * n, -1)
    data_all = jax.tree_util.tree_map(lambda a: np.concatenate([a] * n_starts), data)
    cols = list(free)
    if opts["solver"] == "lm":
        cfg = LMConfig(ftol=opts["ftol"], xtol=opts["rtol"], gtol=opts["gtol"],
                       lambda0=opts["lambda0"], max_steps=opts["max_steps"])
        # a bar on a terminal only, for batches long enough to wait for
        with tqdm(total=len(u_all), desc=f"fitting {model.name}", unit="trial", leave=False,
                  disable=None if len(u_all) >= PROGRESS_MIN_TRIALS else True) as bar:
            u_free, code, steps = solve_pool(normal_fn(model, free), u_all[:, cols], data_all,
                                             cfg, opts["chunk_size"], threads=opts["threads"],
                                             progress=bar.update)
        converged, nonfinite = code == CONVERGED, code == NONFINITE
    else:
        u_free, converged, steps = solve_rounds(
            model, free, u_all[:, cols], data_all, opts["solver"], opts["rtol"], opts["atol"],
            opts["max_steps"], opts["steps_per_round"], opts["chunk_size"])
        nonfinite = ~np.all(np.isfinite(u_free), axis=1)
    u_all = u_all.copy()
    u_all[:, cols] = u_free
    resid, jtj = _at_optimum(model, free, u_all, data_all, opts["chunk_size"])
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is NONFINITE, not a crash
        cost = np.where(nonfinite, np.inf, np.nan_to_num(np.sum(resid**2, axis=1), nan=np.inf))
    best = np.argmin(cost.reshape(n_starts, n), axis=0) * n + np.arange(n)
    return (u_all[best], converged[best], nonfinite[best], steps.reshape(n_starts, n).sum(0),
            resid[best], jtj[best])


def _fit_member(model, t_mask, data, u_start, fixed, opts, extra_starts=None):
    """Fit one member: multi-start solve, statistics; returns a dict of per-trial arrays.

    ``extra_starts`` (k, n_trials, n_params): further starting points (e.g. the
    smaller family member's optimum), tried besides the data-driven ones.
    """
    names = model.param_names
    free = tuple(j for j, n in enumerate(names) if n not in fixed)
    base = u_start.copy()
    for name, value in fixed.items():
        if name in names:
            base[:, names.index(name)] = PARAMS[name].to_unconstrained(value)
    data = (*data, base, opts["noise"])
    starts = multi_starts(model, base, opts["n_starts"], opts["seed"], keys=opts["keys"])
    if extra_starts is not None:
        extra = np.array(extra_starts, dtype=np.float64)
        held = [j for j in range(len(names)) if j not in free]
        extra[:, :, held] = base[None][:, :, held]
        starts = np.concatenate([starts, extra])
    u, converged, nonfinite, steps, resid, jtj = _solve(model, free, starts, data, opts)
    stats = statistics(model, u, resid, jtj, t_mask, free,
                       [n for n in fixed if n in names and n not in opts["tied"]])
    if opts["drive"] == "events":
        flag_fast_loading(stats["flags"], stats["values"], opts["dt"], opts["stroke_mm"])
    status = np.array([
        Status.NONFINITE if nonfinite[i] and t_mask[i].sum() >= 3 * len(free)
        else status_of(len(free), converged[i], u[i], stats["chi2"][i], stats["cond"][i],
                       t_mask[i], saturated=opts["saturated"][i])
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
    y,
    t,
    drive_input,
    *,
    model: str = "auto",
    direction=None,
    drive: str = "events",
    solver: str | BatchedLevenbergMarquardt = "lm",
    max_steps: int = 100,
    steps_per_round: int = 40,
    chunk_size: int = 32,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    ftol: float = 1e-6,
    u0=None,
    n_starts: int = 1,
    seed: int = 0,
    fix: Mapping[str, float] | None = None,
    tie: Sequence[str] = (),
    groups=None,
    stroke_mm: float = 1.0,
    priors: Mapping[str, tuple[float, float] | None] | None = None,
    threads: int | None = None,
) -> FitResult:
    """Fit a contact model to every trial of a batch.

    Parameters
    ----------
    y : array (n_trials, n_samples)
        Force of one channel per trial, N; NaN marks missing samples (masked out).
    t : array (n_samples,)
        Uniform sample times, s (shared by the batch).
    drive_input : tuple or array
        ``(t_out, t_back)`` command times in s (scalars or ``(n_trials,)``) for
        ``drive="events"``; the displacement in mm, ``(n_trials, n_samples)``, for
        ``drive="given"``.
    model : str, default "auto"
        A family member's name, or ``"auto"``: fit every member and keep the
        smallest whose BIC is not beaten by more than ``BIC_TIE``.
    direction : array (n_trials,), optional
        +1/-1 per trial; estimated from the out stroke when omitted.
    solver : {"lm", "optx-lm", "dogleg", "gauss-newton"} or BatchedLevenbergMarquardt
        ``"lm"``: frictionfit's batched Levenberg-Marquardt (lineax Cholesky solves,
        per-trial damping and Marquardt scaling, slot refilling; the fastest);
        the others are the optimistix solvers, vmapped in rounds. A
        :class:`~frictionfit.fit.BatchedLevenbergMarquardt` object runs ``"lm"`` with its
        own tolerances (``rtol``, ``atol``, ``ftol``, ``lambda0``; ``rtol``/``ftol`` here
        are then ignored).
    max_steps, steps_per_round, chunk_size : int
        Step budget per trial; steps per round (optimistix solvers); trials per
        vmapped chunk (the LM's pool size). Pools of 32 were the fastest of 16-256
        on this 2-core machine (512 relaxation trials, 2 threads, median of 3:
        121-124 trials/s at 32, 117 at 64, 97 at 128, 63 at 256; stick_slip 89 vs
        72 at 128; ``model="auto"`` 9.3 vs 8.1): a small pool's state stays in the
        cache, and fewer slots idle while the slowest trials of a pool finish.
    rtol, atol, ftol : float
        Step tolerances (``rtol`` is the LM's ``xtol``); ``ftol``: relative cost
        decrease below which the LM stops.
    u0 : array (n_trials, n_params), optional
        Unconstrained starting points (a single named model only).
    n_starts, seed : int
        Starting points per trial: the data-driven guess plus ``n_starts - 1`` seeded
        jitters of it; the lowest-cost optimum is kept. Each trial's jitter is drawn
        from ``(seed, a key of its own samples)``, so a trial's result does not depend
        on which other trials share its batch.
    fix : mapping name -> physical value, optional
        Parameters held at a known value (flagged "fixed", stderr 0).
    tie, groups : sequence of str, array (n_trials,)
        Parameters shared by the trials of a group (e.g. the channels of one
        measurement). Simplest honest version, not a joint fit: every trial is
        fitted freely, the group's inverse-variance mean of each tied parameter
        is then fixed and the other parameters refitted; the tied parameter
        reports that mean and its combined stderr, flagged "tied".
    stroke_mm : float
        The rig's finger stroke (mm) for ``drive="events"``; stiffness is per mm of it.
    priors : mapping name -> (centre, sd) or None, optional
        Normal priors on parameters' sampling coordinates (for a ``loglogit``
        parameter: median in its unit and sd of the natural log), replacing the
        defaults (:data:`~frictionfit.models.family.RAMP_PRIOR` on ``ramp``);
        ``None`` for a name makes it flat over its bounds. The fit is then the MAP
        estimate; chi-square, AIC and BIC are of the data alone.
    threads : int, optional
        Host threads of the ``"lm"`` solver, each with its own pool of trials (only
        for batches of at least two full pools); results do not depend on it, bit
        for bit. Default: the cores this process may use. On this 2-core machine,
        quiet, 2 threads solved 128 relaxation trials 1.3x faster than one
        (``frictionfit bench fit``, alternated, median of 3); on a heavily shared
        machine they were slower.

    Returns
    -------
    FitResult
        One row per trial, with a Status each: a failed trial never sinks the batch.
        A trial with a run of ``SATURATED_RUN`` samples at its extreme value (a
        clipped channel) is fitted without them and gets ``Status.SATURATED``.

    Examples
    --------
    >>> from frictionfit.simulation.trials import simulate_trials
    >>> ts = simulate_trials("stick_slip", 2, seed=0)
    >>> res = fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model="stick_slip")
    >>> [Status(s).name for s in res.status]
    ['CONVERGED', 'CONVERGED']
    """
    start = time.perf_counter()
    y = np.atleast_2d(np.asarray(y, dtype=np.float64))
    t = np.asarray(t, dtype=np.float64)
    if y.shape[1] != t.size:
        raise FitError(f"y has {y.shape[1]} samples per trial but t has {t.size}")
    lm = BatchedLevenbergMarquardt(rtol=rtol, ftol=ftol)
    if isinstance(solver, BatchedLevenbergMarquardt):
        lm, solver = solver, "lm"
    if solver not in SOLVERS:
        raise FitError(f"unknown solver {solver!r}; choose from {SOLVERS} or a "
                       "BatchedLevenbergMarquardt")
    dt = float(t[1] - t[0]) if t.size > 1 else 1.0
    if t.size > 2 and not np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-12):
        raise FitError("t must be uniformly sampled (re-grid missing samples as NaN)")
    n_trials = y.shape[0]
    fix = dict(fix or {})
    unknown = [n for n in [*fix, *tie] if n not in PARAMS]
    if unknown:
        raise FitError(f"cannot fix or tie unknown parameter(s) {unknown}; "
                       f"parameters are {list(PARAMS)}")
    if tie and groups is None:
        raise FitError("tie needs groups: one group label per trial (e.g. the measurement id)")
    # Samples held at a clipping extreme are censored, not measured: left out (SATURATED).
    clipped = saturated_samples(y)
    mask = FitResult.sample_mask(y)
    y_clean = np.where(mask, y, 0.0)
    if drive == "events":
        t_out, t_back = drive_input
        drive_input = (np.broadcast_to(np.asarray(t_out, np.float64), (n_trials,)).copy(),
                       np.broadcast_to(np.asarray(t_back, np.float64), (n_trials,)).copy())
        guess_times = drive_input
    else:
        drive_input = np.asarray(drive_input, dtype=np.float64).reshape(n_trials, t.size)
        guess_times = (np.full(n_trials, t[0]), np.full(n_trials, t[-1] + 1.0))
    if direction is None:
        direction = direction_of(t, y, *guess_times)
    direction = np.asarray(direction, dtype=np.float64)
    data = (y_clean, mask, drive_input, direction, np.full(n_trials, t[0]), np.full(n_trials, dt))
    opts = dict(solver=solver, rtol=lm.rtol, atol=atol, ftol=lm.ftol, gtol=lm.atol,
                lambda0=lm.lambda0, max_steps=max_steps,
                steps_per_round=steps_per_round, chunk_size=chunk_size,
                n_starts=max(int(n_starts), 1), seed=seed, tied=(), keys=trial_keys(y),
                saturated=clipped.any(axis=1), drive=drive, dt=dt, stroke_mm=stroke_mm,
                noise=noise_scale(y_clean, mask),
                threads=available_cores() if threads is None else max(int(threads), 1))
    names = [m.name for m in FAMILY] if model == "auto" else [model]
    try:
        members = [get_model(n, drive=drive, stroke_mm=stroke_mm, priors=priors) for n in names]
    except ValueError as exc:
        raise FitError(str(exc)) from None
    fits, previous, inits = {}, None, {}
    for member in members:
        start_u = np.array(u0 if (u0 is not None and model != "auto") else initial_guess(
            member, t, y, *guess_times, direction), dtype=np.float64)
        inits[member.name] = [{k: float(v) for k, v in row.items()}
                              for row in _rows_of(member.physical(start_u))]
        fit = _fit_member(member, mask, data, start_u, fix, opts,
                          _warm_start(member, start_u, previous))
        if tie:
            means, errs = _tie(fit, member, tie, np.asarray(groups))
            refit = _fit_member(member, mask, data, fit["u"], {**fix, **means},
                                dict(opts, tied=tuple(means)))
            for i in range(n_trials):
                for name in means:
                    refit["stderr"][i][name] = float(errs[name][i])
                # Holding a tied parameter at its group mean hides the trade-offs it had:
                # what the free fit could not identify stays flagged.
                for name, flag in fit["flags"][i].items():
                    refit["flags"][i].setdefault(name, flag)
            fit = refit
        fits[member.name] = fit
        previous = (member, fit["u"])
    if model == "auto" and not tie:
        # Backward pass: a smaller member also starts from the bigger one's optimum
        # (extra effects dropped), so a smaller member stuck in a poor local minimum
        # is not out-scored by a bigger one that found the right basin.
        for small, big in reversed(list(zip(members[:-1], members[1:], strict=True))):
            back = _warm_start(small, fits[small.name]["u"], (big, fits[big.name]["u"]))
            fits[small.name] = _fit_member(small, mask, data, fits[small.name]["u"], fix,
                                           opts, back)
    bic = pd.DataFrame({n: fits[n]["bic"] for n in names})
    chosen = choose(bic)
    rows = [fits[name] for name in chosen]
    with np.errstate(over="ignore", invalid="ignore"):
        total_ss = np.array([np.sum((yi[m] - yi[m].mean()) ** 2) if m.any() else np.nan
                             for yi, m in zip(y, mask, strict=True)])
        chi2 = np.array([r["chi2"][i] for i, r in enumerate(rows)])
        # A constant (dead) channel has no variance to explain: R^2 is undefined (NaN).
        r2 = 1.0 - np.divide(chi2, total_ss, out=np.full_like(chi2, np.nan),
                             where=total_ss > 0)
    pick = {k: np.array([r[k][i] for i, r in enumerate(rows)])
            for k in ("chi2", "redchi", "aic", "bic", "cond", "steps", "status")}
    return FitResult(
        model=list(chosen), values=[r["values"][i] for i, r in enumerate(rows)],
        stderr=[r["stderr"][i] for i, r in enumerate(rows)],
        flags=[r["flags"][i] for i, r in enumerate(rows)], status=pick["status"],
        chi2=pick["chi2"], redchi=pick["redchi"], aic=pick["aic"], bic=pick["bic"],
        r2=r2, cond=pick["cond"], n_steps=pick["steps"],
        u=[r["u"][i] for i, r in enumerate(rows)],
        init=[inits[name][i] for i, name in enumerate(chosen)],
        correl=[r["correl"][i] for i, r in enumerate(rows)],
        bic_table=bic if model == "auto" else None, wall_s=time.perf_counter() - start,
        solver=solver, n_starts=opts["n_starts"], direction=direction,
        drive_input=drive_input, drive=drive, stroke_mm=stroke_mm,
        priors=dict(priors) if priors is not None else None,
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
