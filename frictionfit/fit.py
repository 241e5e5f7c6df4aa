"""Batched per-trial least-squares fits of the contact-model family with optimistix.

Each trial (one motion of one force channel) is fitted with
``optimistix.least_squares`` (Levenberg-Marquardt by default), ``throw=False``,
vmapped over a fixed-size chunk of trials. A vmapped while-loop runs every trial
of a chunk until the slowest finishes, so solves run in *rounds* of
``steps_per_round`` steps: after each round only the unconverged trials are
re-batched (same chunk shape, so nothing recompiles) and restarted from where
they stopped. Forward-mode Jacobians (few parameters, thousands of residuals).

Statistics follow lmfit: covariance ``sigma^2 pinv(J^T J)`` in unconstrained
coordinates, mapped to physical standard errors by the delta method; chi-square,
reduced chi-square, AIC, BIC (with the sample count deflated by the residuals'
lag-1 autocorrelation), R^2 and the condition number. Parameters whose standard
error exceeds their value, or that sit on a bound, are flagged non-identifiable.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import lru_cache

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pandas as pd

from frictionfit.errors import FitError, Status
from frictionfit.models import FAMILY, PARAMS, ContactModel, get_model

__all__ = ["FitResult", "fit_report", "fit_trials", "initial_guess"]

SOLVERS = ("lm", "dogleg", "gauss-newton")
#: J^T J condition number (after column scaling) above which a fit is ill-conditioned.
ILL_CONDITIONED = 1e12
#: BIC differences below this are ties, resolved in favour of the smaller model.
BIC_TIE = 2.0


def _solver(name: str, rtol: float, atol: float):
    if name == "lm":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    if name == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol)
    if name == "gauss-newton":
        return optx.GaussNewton(rtol=rtol, atol=atol)
    raise FitError(f"unknown solver {name!r}; choose from {SOLVERS}")


def _residual(model: ContactModel):
    def residual(u, args):
        y, mask, drive_input, direction, t = args
        pred = model.predict(u, t, drive_input, direction)
        return jnp.where(mask, pred - y, 0.0)

    return residual


@lru_cache(maxsize=64)
def _chunk_solver(model: ContactModel, solver: str, rtol: float, atol: float, steps: int):
    """A jitted, vmapped solve of one chunk; cached so a second batch never recompiles."""
    residual = _residual(model)
    opt = _solver(solver, rtol, atol)

    def one(u0, y, mask, drive_input, direction, t):
        sol = optx.least_squares(
            residual, opt, u0, args=(y, mask, drive_input, direction, t),
            max_steps=steps, throw=False, options={"jac": "fwd"},
        )
        # A whole Solution cannot leave vmap; return plain arrays.
        return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]

    return eqx.filter_jit(jax.vmap(one, in_axes=(0, 0, 0, 0, 0, None)))


@lru_cache(maxsize=64)
def _jacobian(model: ContactModel):
    residual = _residual(model)

    def one(u, y, mask, drive_input, direction, t):
        args = (y, mask, drive_input, direction, t)
        return residual(u, args), jax.jacfwd(residual)(u, args)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, 0, 0, None)))


def _median(x: np.ndarray, default: float = 0.0) -> float:
    """Median of the finite values of ``x``; ``default`` when there are none."""
    finite = x[np.isfinite(x)]
    return float(np.median(finite)) if finite.size else default


def _out_strokes(t, y, t_out, t_back):
    """Per trial: baseline offset (N) and the finite out-stroke samples ``(times, y - offset)``."""
    t_out = np.broadcast_to(np.asarray(t_out, dtype=np.float64), (y.shape[0],))
    t_back = np.broadcast_to(np.asarray(t_back, dtype=np.float64), (y.shape[0],))
    for yi, to, tb in zip(y, t_out, t_back, strict=True):
        offset = _median(yi[t < to], default=_median(yi))
        window = (t >= to) & (t < tb)
        dev = yi[window] - offset
        finite = np.isfinite(dev)
        yield to, offset, t[window][finite], dev[finite]


def initial_guess(model: ContactModel, t, y, t_out, t_back, direction) -> np.ndarray:
    """Data-driven starting points (unconstrained, ``(n_trials, n_params)``).

    Offset from the samples before the out command; motor delay from the force
    onset; friction from the peak of the out stroke; stiffness from the peak force
    over the (raised-cosine) displacement reached between onset and peak;
    relaxation from the drop between the peak and the end of the out phase.
    """
    y = np.asarray(y, dtype=np.float64)
    rows = []
    strokes = _out_strokes(t, y, t_out, t_back)
    for (to, offset, tw, dev), d in zip(strokes, direction, strict=True):
        out = d * dev
        peak = max(float(out.max()), 1e-3) if out.size else 1e-3
        end = float(np.median(out[-50:])) if out.size >= 50 else 0.5 * peak
        guess = dict(offset=offset, f_kin=0.8 * peak, f_static_excess=0.2 * peak,
                     relax_frac=float(np.clip(1 - end / peak, 0.05, 0.9)))
        if out.size:
            t_peak = tw[np.argmax(out)]
            t_onset = tw[np.argmax(out > 0.1 * peak)]
            guess["delay"] = float(np.clip(t_onset - to, 0.002, 0.25))
            ramp = PARAMS["ramp"].default
            reached = 0.5 - 0.5 * np.cos(np.pi * np.clip((t_peak - t_onset) / ramp, 0.02, 1.0))
            guess["k"] = float(np.clip(peak / (reached * model.stroke_mm), 1e-2, 5e3))
        rows.append([
            PARAMS[n].to_unconstrained(guess.get(n, PARAMS[n].default)) for n in model.param_names
        ])
    return np.asarray(rows, dtype=np.float64)


def _direction(t, y, t_out, t_back) -> np.ndarray:
    """+1/-1 per trial: the sign of the largest deviation during the out phase."""
    return np.asarray([1.0 if dev.size == 0 or dev.max() >= -dev.min() else -1.0
                       for _, _, _, dev in _out_strokes(t, y, t_out, t_back)])


@dataclass
class FitResult:
    """Per-trial fit results, one row per trial; values in physical units.

    Attributes
    ----------
    model : list of str
        The model fitted (or chosen, with ``model="auto"``) per trial.
    values, stderr : list of dict
        Physical parameter values and standard errors per trial (NaN stderr only
        where the covariance could not be computed; such parameters are flagged).
    flags : list of dict
        Per parameter, a short reason it is not identifiable ("at bound",
        "stderr > value", "singular"), absent when it is fine.
    status : ndarray of Status codes
    chi2, redchi, aic, bic, r2, cond : ndarray
    n_steps : ndarray
        Solver steps used.
    bic_table : DataFrame or None
        With ``model="auto"``: BIC per trial (rows) and family member (columns).
    wall_s : float
        Wall time of the whole batch, s.
    """

    model: list[str]
    values: list[dict]
    stderr: list[dict]
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

    @property
    def n_trials(self) -> int:
        return len(self.model)

    def to_frame(self, ids=None) -> pd.DataFrame:
        """One row per trial: id, model, status, each parameter with stderr and unit, stats."""
        rows = []
        for i in range(self.n_trials):
            row = {"trial": i if ids is None else ids[i], "model": self.model[i],
                   "status": Status(int(self.status[i])).name.lower()}
            for name, v in self.values[i].items():
                unit = PARAMS[name].unit
                row[f"{name} [{unit}]"] = v
                row[f"{name}_stderr [{unit}]"] = self.stderr[i][name]
                row[f"{name}_flag"] = self.flags[i].get(name, "")
            for stat in ("chi2", "redchi", "aic", "bic", "r2", "cond", "n_steps"):
                row[stat] = getattr(self, stat)[i]
            row["wall_s_per_trial"] = self.wall_s / max(self.n_trials, 1)
            rows.append(row)
        return pd.DataFrame(rows)


def _statistics(model, u, resid, jac, mask):
    """lmfit-style statistics for one family member over a batch (NumPy)."""
    n = mask.sum(axis=1).astype(np.float64)
    p = model.n_params
    chi2 = np.sum(resid**2, axis=1)
    dof = np.maximum(n - p, 1.0)
    redchi = chi2 / dof
    # Effective sample count: residuals of rubbing signals are autocorrelated, and
    # n independent samples would inflate every BIC difference.
    r0, r1 = resid[:, :-1], resid[:, 1:]
    rho = np.clip(np.sum(r0 * r1, axis=1) / np.maximum(chi2, 1e-300), 0.0, 0.99)
    n_eff = np.maximum(n * (1 - rho) / (1 + rho), p + 2.0)
    loglike_term = n_eff * np.log(np.maximum(chi2 / np.maximum(n, 1.0), 1e-300))
    aic = loglike_term + 2 * p
    bic = loglike_term + p * np.log(n_eff)
    values, stderrs, flags, conds = [], [], [], []
    for i in range(u.shape[0]):
        if not (np.all(np.isfinite(jac[i])) and np.all(np.isfinite(u[i]))):
            # Non-finite Jacobian: this trial's statistics are undefined; flag, don't raise.
            names = model.param_names
            values.append({n: float(p.to_physical(np.float64(np.nan_to_num(u[i, j]))))
                           for j, (n, p) in enumerate(zip(names, model.params, strict=True))})
            stderrs.append(dict.fromkeys(names, np.nan))
            flags.append(dict.fromkeys(names, "singular"))
            conds.append(np.inf)
            chi2[i] = np.nan
            continue
        jtj = jac[i].T @ jac[i]
        scale = np.sqrt(np.maximum(np.diag(jtj), 1e-300))
        scaled = jtj / np.outer(scale, scale)
        ev = np.linalg.eigvalsh(scaled)
        cond = float(ev[-1] / ev[0]) if ev[0] > 0 else np.inf
        cov_u = redchi[i] * np.linalg.pinv(jtj, rcond=1e-13, hermitian=True)
        phys = {}
        err = {}
        flag = {}
        for j, par in enumerate(model.params):
            # Delta method: d(physical)/du by a central difference of the transform.
            h = 1e-6
            v = float(par.to_physical(np.float64(u[i, j])))
            dv = (float(par.to_physical(np.float64(u[i, j] + h)))
                  - float(par.to_physical(np.float64(u[i, j] - h)))) / (2 * h)
            var = cov_u[j, j]
            se = abs(dv) * np.sqrt(var) if var >= 0 and np.isfinite(var) else np.nan
            phys[par.name] = v
            err[par.name] = float(se)
            if par.at_bound(v):
                flag[par.name] = "at bound"
            elif not np.isfinite(se) or scale[j] < 1e-12:
                flag[par.name] = "singular"
            elif par.transform != "identity" and se > abs(v):
                flag[par.name] = "stderr > value"
        values.append(phys)
        stderrs.append(err)
        flags.append(flag)
        conds.append(cond)
    return dict(values=values, stderr=stderrs, flags=flags, chi2=chi2, redchi=redchi,
                aic=aic, bic=bic, cond=np.asarray(conds))


def _padded(idx: np.ndarray, chunk_size: int) -> np.ndarray:
    """``idx`` padded to ``chunk_size`` by repeating its last entry (one compiled shape)."""
    return np.concatenate([idx, np.full(chunk_size - idx.size, idx[-1])])


def _rows(arrays, idx):
    """The rows ``idx`` of every array in a pytree, as JAX arrays."""
    return jax.tree_util.tree_map(lambda a: jnp.asarray(a[idx]), arrays)


def _fit_member(model, t, y, mask, drive_input, direction, u0, solver, rtol, atol,
                max_steps, steps_per_round, chunk_size):
    """Fit one member to every trial in rounds; returns u, converged, steps, statistics."""
    n_trials = y.shape[0]
    steps_per_round = min(steps_per_round, max_steps)
    solve = _chunk_solver(model, solver, rtol, atol, steps_per_round)
    u = u0.copy()
    converged = np.zeros(n_trials, dtype=bool)
    steps = np.zeros(n_trials, dtype=np.int64)
    active = np.arange(n_trials)
    tj = jnp.asarray(t)
    while active.size:
        for start in range(0, active.size, chunk_size):
            idx = active[start:start + chunk_size]
            u_new, ok, nst = solve(
                *_rows((u, y, mask, drive_input, direction), _padded(idx, chunk_size)), tj)
            u[idx] = np.asarray(u_new)[: idx.size]
            converged[idx] = np.asarray(ok)[: idx.size]
            steps[idx] += np.asarray(nst)[: idx.size]
        active = active[~converged[active] & (steps[active] < max_steps)
                        & np.all(np.isfinite(u[active]), axis=1)]
    resid_j, jac_j = [], []
    jacobian = _jacobian(model)
    for start in range(0, n_trials, chunk_size):
        idx = np.arange(start, min(start + chunk_size, n_trials))
        r, jm = jacobian(*_rows((u, y, mask, drive_input, direction), _padded(idx, chunk_size)), tj)
        resid_j.append(np.asarray(r)[: idx.size])
        jac_j.append(np.asarray(jm)[: idx.size])
    resid = np.concatenate(resid_j)
    jac = np.concatenate(jac_j)
    stats = _statistics(model, u, resid, jac, mask)
    return u, converged, steps, stats


def fit_trials(
    y,
    t,
    drive_input,
    *,
    model: str = "auto",
    direction=None,
    drive: str = "events",
    solver: str = "lm",
    max_steps: int = 200,
    steps_per_round: int = 40,
    chunk_size: int = 32,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    u0=None,
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
    solver : {"lm", "dogleg", "gauss-newton"}
        optimistix least-squares solver.
    max_steps, steps_per_round, chunk_size : int
        Step budget per trial, steps per round, trials per vmapped chunk.
    u0 : array (n_trials, n_params), optional
        Unconstrained starting points (a single named model only).

    Returns
    -------
    FitResult
        One row per trial, with a Status each: a failed trial never sinks the batch.

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
    n_trials = y.shape[0]
    mask = np.isfinite(y)
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
        direction = _direction(t, y, *guess_times)
    direction = np.asarray(direction, dtype=np.float64)
    names = [m.name for m in FAMILY] if model == "auto" else [model]
    members = [get_model(n, drive=drive) for n in names]
    fits = {}
    for member in members:
        start_u = u0 if (u0 is not None and model != "auto") else initial_guess(
            member, t, y, *guess_times, direction)
        fits[member.name] = _fit_member(
            member, t, y_clean, mask, drive_input, direction, np.array(start_u, dtype=np.float64),
            solver, rtol, atol, max_steps, steps_per_round, chunk_size)
    bic = pd.DataFrame({n: fits[n][3]["bic"] for n in names})
    chosen = _choose(bic)
    out = {k: [] for k in ("model", "values", "stderr", "flags", "u")}
    arrays = {k: np.empty(n_trials) for k in ("chi2", "redchi", "aic", "bic", "cond")}
    status = np.empty(n_trials, dtype=np.int64)
    n_steps = np.empty(n_trials, dtype=np.int64)
    total_ss = np.array([np.sum((yi[m] - yi[m].mean()) ** 2) if m.any() else np.nan
                         for yi, m in zip(y, mask, strict=True)])
    for i, name in enumerate(chosen):
        member = next(m for m in members if m.name == name)
        u, converged, steps, stats = fits[name]
        out["model"].append(name)
        for key in ("values", "stderr", "flags"):
            out[key].append(stats[key][i])
        out["u"].append(u[i])
        for key in arrays:
            arrays[key][i] = stats[key][i]
        n_steps[i] = steps[i]
        status[i] = _status(member, converged[i], u[i], stats, i, mask[i])
    r2 = 1.0 - arrays["chi2"] / total_ss
    return FitResult(
        model=out["model"], values=out["values"], stderr=out["stderr"], flags=out["flags"],
        status=status, r2=r2, n_steps=n_steps, u=out["u"],
        bic_table=bic if model == "auto" else None, wall_s=time.perf_counter() - start,
        **arrays,
    )


def _choose(bic: pd.DataFrame) -> list[str]:
    """Per trial, the smallest member whose BIC is within BIC_TIE of the best."""
    values = bic.to_numpy()
    best = np.nanmin(np.where(np.isfinite(values), values, np.inf), axis=1)
    chosen = []
    for i, b in enumerate(best):
        ok = np.flatnonzero(values[i] <= b + BIC_TIE)
        chosen.append(bic.columns[ok[0]] if ok.size else bic.columns[0])
    return chosen


def _status(model, converged, u, stats, i, mask) -> Status:
    if mask.sum() < 3 * model.n_params:
        return Status.INSUFFICIENT_DATA
    if not (np.all(np.isfinite(u)) and np.isfinite(stats["chi2"][i])):
        return Status.NONFINITE
    if not converged:
        return Status.MAX_STEPS
    if stats["cond"][i] > ILL_CONDITIONED:
        return Status.ILL_CONDITIONED
    return Status.CONVERGED


def fit_report(result: FitResult, i: int = 0) -> str:
    """An lmfit-style report of trial ``i``: statistics, values +/- stderr (%), flags."""
    lines = [
        f"[[Model]]\n    {result.model[i]}",
        "[[Fit Statistics]]",
        f"    status             = {Status(int(result.status[i])).name}"
        f" ({Status(int(result.status[i])).message})",
        f"    solver steps       = {result.n_steps[i]}",
        f"    chi-square         = {result.chi2[i]:.6g}",
        f"    reduced chi-square = {result.redchi[i]:.6g}",
        f"    Akaike info crit   = {result.aic[i]:.6g}",
        f"    Bayesian info crit = {result.bic[i]:.6g}",
        f"    R-squared          = {result.r2[i]:.6g}",
        f"    condition number   = {result.cond[i]:.3g}",
        "[[Variables]]",
    ]
    for name, v in result.values[i].items():
        se = result.stderr[i][name]
        unit = PARAMS[name].unit
        pct = f" ({100 * se / abs(v):.2f}%)" if np.isfinite(se) and v != 0 else ""
        flag = result.flags[i].get(name)
        warn = f"  <-- not identifiable: {flag}" if flag else ""
        lines.append(f"    {name:16s} = {v:.6g} +/- {se:.3g}{pct} {unit}{warn}")
    if result.bic_table is not None:
        lines.append("[[BIC by model]]")
        for name, b in result.bic_table.iloc[i].items():
            mark = "  <-- chosen" if name == result.model[i] else ""
            lines.append(f"    {name:16s} {b:.6g}{mark}")
    return "\n".join(lines)
