"""lmfit-style statistics of a batch at its optimum, identifiability flags, status, BIC choice.

Covariance ``sigma^2 pinv(J^T J)`` (or the inverse of a given likelihood Hessian) in
unconstrained coordinates, mapped to physical
standard errors by the delta method; chi-square, reduced chi-square, and the
condition number of the column-scaled ``J^T J``.

AIC and BIC come from the Gaussian AR(1) likelihood of the residuals, the noise's
lag-1 coefficient ``rho`` and innovation variance profiled out (one more fitted
parameter): ``-2 log L = n log(S / n) - g log(1 - rho^2)`` with ``S`` the
prewhitened sum of squares (``r_t - rho r_{t-1}``; the first sample of each of the
``g`` contiguous runs of finite samples scaled by ``sqrt(1 - rho^2)``). Rubbing
residuals are autocorrelated, and the white-noise likelihood would then inflate
every BIC difference; white residuals give ``rho ~ 0`` and the ordinary BIC. Each
member's BIC is a likelihood of the same data in the same units, so the
differences are comparable. The likelihood is :mod:`frictionfit.fit._noise`'s, the one
behind the covariances and the posteriors too.

A parameter is flagged (not reported as a confident number) when it sits on a
bound, when its standard error is undefined or exceeds its value, or when it is
almost perfectly correlated (``|corr| > CORRELATED``) with another parameter: then
only a combination of the two is determined by the trial (for instance the
stiffness, the movement duration and the slip-weakening length while the contact
sticks on the quadratic start of the drive), and when it only shapes an effect whose
size is not told apart from zero (``GATED``: a relaxation time without relaxation).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from frictionfit.errors import Status
from frictionfit.fit._noise import RHO_MAX, ar1_deviance
from frictionfit.fit._numerics import fd_slope, scaled_condition
from frictionfit.models import PARAMS, ContactModel

__all__ = ["BIC_TIE", "CORRELATED", "GATED", "GATE_SDS", "ILL_CONDITIONED",
           "MIN_LOADING_SAMPLES", "RHO_MAX", "VANISHING", "ar1_deviance", "choose",
           "WIDER", "flag_fast_loading", "flag_gated", "set_covariance", "statistics",
           "status_of"]

#: J^T J condition number (after column scaling) above which a fit is ill-conditioned.
ILL_CONDITIONED = 1e12
#: BIC differences below this are ties, resolved in favour of the smaller model.
BIC_TIE = 2.0
#: |correlation| above which two parameters are flagged as trading off.
CORRELATED = 0.99
#: A parameter that only shapes an effect (key) whose size (value) is not
#: distinguished from its lower bound (no effect) by GATE_SDS stderr is flagged:
#: tau of a relaxation that is not seen, the slip length of an absent static peak.
GATED = {"tau": "relax_frac", "tau2": "relax_frac2", "slip_length": "f_static_excess"}
GATE_SDS = 2.0
#: Flags of a parameter whose column of the Jacobian vanishes: one pinned at a bound (a
#: static peak the data do not show, a branch that relaxes as far as allowed) and one
#: that no longer acts ("singular": a branch's time when its fraction sits at 0).
VANISHING = ("at bound", "singular")
#: Flag of a (positive) parameter whose standard error exceeds its value.
WIDER = "stderr > value"
_GATED_BY = " not distinguishable from "


def _delta(par, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Physical values and d(physical)/du (central difference of the transform)."""
    u = np.asarray(u, dtype=np.float64)
    return par.to_physical(u), fd_slope(par.to_physical, u)


def _covariances(jtj: np.ndarray, redchi: np.ndarray, hessian: np.ndarray | None = None):
    """Per trial (stacked, finite inputs): column scale, condition number of the scaled
    ``J^T J``, variances, correlations and the covariance: ``redchi pinv(J^T J)``, or
    ``pinv(hessian)`` where the likelihood's Hessian is given. The column scale (behind the
    "singular" flag) is that of ``J^T J`` in the units of the residuals over the noise's
    variance relative to ``redchi``: ``redchi hessian`` when given."""
    info = jtj if hessian is None else redchi[:, None, None] * hessian
    scale = np.sqrt(np.maximum(np.einsum("nii->ni", info), 1e-300))
    cond = scaled_condition(jtj)
    cov = (redchi[:, None, None] * np.linalg.pinv(jtj, rcond=1e-13, hermitian=True)
           if hessian is None else np.linalg.pinv(hessian, rcond=1e-13, hermitian=True))
    var = np.einsum("nii->ni", cov)
    sd = np.sqrt(np.clip(var, 0.0, None))
    corr = cov / np.maximum(sd[:, :, None] * sd[:, None, :], 1e-300)
    corr[:, np.arange(sd.shape[1]), np.arange(sd.shape[1])] = 0.0
    return scale, cond, var, corr, cov


def _flags(model: ContactModel, values, errs, scale, corr, free, fixed_names):
    """Flags of one trial's parameters (see the module docstring)."""
    flags = {}
    pos = dict(zip(free, range(len(free)), strict=True))
    for j, par in enumerate(model.params):
        if j not in pos:
            flags[par.name] = "fixed" if par.name in fixed_names else "tied"
            continue
        jj, v, se = pos[j], values[par.name], errs[par.name]
        partner = int(np.argmax(np.abs(corr[jj]))) if len(free) > 1 else jj
        if par.at_bound(v):
            flags[par.name] = "at bound"
        elif not np.isfinite(se) or scale[jj] < 1e-12:
            flags[par.name] = "singular"
        elif _wider_than_value(par, v, se):
            flags[par.name] = WIDER
        elif len(free) > 1 and abs(corr[jj, partner]) > CORRELATED:
            flags[par.name] = f"trades off with {model.param_names[free[partner]]}"
    flag_gated(flags, values, errs)
    return flags


def _pairs(corr: np.ndarray, names: list[str]) -> dict:
    """``(name_a, name_b) -> correlation`` of each pair (a before b) of a correlation matrix."""
    return {(a, b): float(corr[ja, jb]) for ja, a in enumerate(names)
            for jb, b in enumerate(names) if jb > ja}


def _wider_than_value(par, value: float, stderr: float) -> bool:
    """A positive parameter whose standard error exceeds its value."""
    return not par.signed and stderr > abs(value)


def set_covariance(model: ContactModel, u: np.ndarray, stats: dict, free: tuple[int, ...],
                   cov: np.ndarray) -> None:
    """Put ``cov`` (n_trials, p_free, p_free; unconstrained coordinates) as each trial's
    covariance in ``stats`` (:func:`statistics`' output; in place) where the trial's is
    finite. Standard errors and correlations follow, and so do the flags that depend on
    them: a parameter wider than its value, or only shaping an effect not told apart from
    none (:func:`_flags`' rules; the other flags stay)."""
    names = [model.param_names[j] for j in free]
    slope = {model.param_names[j]: _delta(model.params[j], np.nan_to_num(u[:, j]))[1]
             for j in free}
    for i in range(len(stats["cov"])):
        if not (np.all(np.isfinite(stats["cov"][i])) and np.all(np.isfinite(cov[i]))):
            continue
        stats["cov"][i] = cov[i]
        sd = np.sqrt(np.clip(np.diag(cov[i]), 0.0, None))
        errs, flags, values = stats["stderr"][i], stats["flags"][i], stats["values"][i]
        for name in [n for n, f in flags.items()
                     if f == WIDER or (n in GATED and _GATED_BY in f)]:
            del flags[name]
        for jj, name in enumerate(names):
            errs[name] = float(abs(slope[name][i]) * sd[jj])
            par = model.params[free[jj]]
            if name not in flags and _wider_than_value(par, values[name], errs[name]):
                flags[name] = WIDER
        stats["correl"][i] = _pairs(cov[i] / np.maximum(np.outer(sd, sd), 1e-300), names)
        flag_gated(flags, values, errs)


def flag_gated(flags: dict, values: dict, errs: dict) -> None:
    """Flag (in place) each unflagged parameter that only shapes an effect whose size is
    within GATE_SDS stderr of none (:data:`GATED`)."""
    for shape, size in GATED.items():
        if shape in flags or size not in values or shape not in values:
            continue
        lower = PARAMS[size].lower
        if not values[size] - GATE_SDS * errs[size] > lower + 1e-12 * max(abs(lower), 1.0):
            flags[shape] = f"{size}{_GATED_BY}{lower:g}"


#: Samples of sticking below which the stiffness is not measured (only bounded below).
MIN_LOADING_SAMPLES = 2.0


def flag_fast_loading(flags, values, dt: float, stroke_mm: float) -> None:
    """Flag ``k`` (in place) where the fitted contact loads within MIN_LOADING_SAMPLES samples.

    With the raised-cosine drive (``drive="events"``) the spring reaches the static
    limit ``(f_kin + f_static_excess) / k`` after ``ramp / pi * arccos(1 - 2 z / stroke)``
    s. When that is about one sample, any stiffer contact fits the data as well: the
    likelihood is one-sided in ``k`` and its Gaussian stderr is no interval.
    """
    for f, v in zip(flags, values, strict=True):
        if "k" in f or not {"k", "f_kin", "ramp"} <= set(v):
            continue
        z = (v["f_kin"] + v.get("f_static_excess", 0.0)) / v["k"]
        if not 0.0 <= z < stroke_mm:
            continue  # never slips: the whole loading is seen
        t_load = v["ramp"] / np.pi * np.arccos(1.0 - 2.0 * z / stroke_mm)
        if t_load < MIN_LOADING_SAMPLES * dt:
            f["k"] = f"loads within {t_load / dt:.1f} samples (a lower bound)"


def statistics(model: ContactModel, u, resid, jtj, mask, free=None, fixed_names=(),
               hessian=None):
    """Statistics of one family member over a batch (NumPy).

    ``u`` (n_trials, n_params) full unconstrained optimum; ``resid`` (n_trials,
    n_samples) masked residuals (N); ``jtj`` (n_trials, p_free, p_free) over the free
    parameters ``free`` (indices; all by default); ``fixed_names`` the parameters
    held fixed by the user (the other non-free ones are tied). ``hessian`` (like
    ``jtj``, optional): the Gauss-Newton Hessian of ``-log posterior`` under the AR(1)
    noise (:mod:`frictionfit.fit._noise`), whose inverse is then the covariance;
    otherwise it is the white-noise ``redchi pinv(J^T J)``.
    """
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # overflow -> NONFINITE
        return _statistics(model, u, resid, jtj, mask, free, fixed_names, hessian)


def _statistics(model: ContactModel, u, resid, jtj, mask, free=None, fixed_names=(),
                hessian=None):
    free = tuple(range(model.n_params)) if free is None else tuple(free)
    n = mask.sum(axis=1).astype(np.float64)
    p = len(free)
    chi2 = np.sum(resid**2, axis=1)
    redchi = chi2 / np.maximum(n - p, 1.0)
    m2 = ar1_deviance(resid, mask)
    aic = m2 + 2 * (p + 1)
    bic = m2 + (p + 1) * np.log(np.maximum(n, 1.0))
    names = model.param_names
    ok = (np.all(np.isfinite(jtj), axis=(1, 2)) & np.all(np.isfinite(u), axis=1)
          & np.isfinite(chi2))
    if hessian is not None:
        ok &= np.all(np.isfinite(hessian), axis=(1, 2))
    chi2[~ok] = np.nan
    phys, slope = zip(*(_delta(par, np.nan_to_num(u[:, j])) for j, par in enumerate(model.params)),
                      strict=True)
    n_trials = u.shape[0]
    scale, var = np.full((n_trials, p), np.nan), np.full((n_trials, p), np.nan)
    corr, cond = np.zeros((n_trials, p, p)), np.full(n_trials, np.inf)
    cov = np.full((n_trials, p, p), np.nan)
    if ok.any():
        scale[ok], cond[ok], var[ok], corr[ok], cov[ok] = _covariances(
            jtj[ok], redchi[ok], None if hessian is None else hessian[ok])
    pos = {j: jj for jj, j in enumerate(free)}
    sd = np.sqrt(np.where(var >= 0, var, np.nan))
    se = np.stack([np.abs(slope[j]) * sd[:, pos[j]] if j in pos else np.zeros(n_trials)
                   for j in range(model.n_params)], axis=1)
    values, stderrs, flags, correls = [], [], [], []
    free_names = [names[j] for j in free]
    for i in range(u.shape[0]):
        values.append({nm: float(phys[j][i]) for j, nm in enumerate(names)})
        # the physical maps are increasing: correlations carry over from the fit's coordinates
        correls.append(_pairs(corr[i] if ok[i] else np.full_like(corr[i], np.nan), free_names))
        if not ok[i]:  # non-finite Jacobian: statistics undefined; flag, don't raise
            stderrs.append(dict.fromkeys(names, np.nan))
            flags.append(dict.fromkeys(names, "singular"))
            continue
        stderrs.append({nm: float(se[i, j]) for j, nm in enumerate(names)})
        flags.append(_flags(model, values[i], stderrs[i], scale[i], corr[i], free,
                            set(fixed_names)))
    return dict(values=values, stderr=stderrs, flags=flags, chi2=chi2, redchi=redchi,
                aic=aic, bic=bic, cond=cond, correl=correls, cov=cov,
                ndata=n.astype(np.int64), nvarys=np.full(n_trials, p, dtype=np.int64))


def choose(bic: pd.DataFrame) -> list[str]:
    """Per trial, the smallest member whose BIC is within BIC_TIE of the best."""
    values = bic.to_numpy()
    best = np.nanmin(np.where(np.isfinite(values), values, np.inf), axis=1)
    chosen = []
    for i, b in enumerate(best):
        ok = np.flatnonzero(values[i] <= b + BIC_TIE)
        chosen.append(bic.columns[ok[0]] if ok.size else bic.columns[0])
    return chosen


#: Parameters that set the force's scale: one at a bound of its range is no measurement
#: (:attr:`Status.AT_BOUND`), unlike an effect's size at its "absent" bound.
SCALE_PARAMS = ("k", "f_kin")


def status_of(n_free: int, converged: bool, u, chi2: float, cond: float, mask,
              saturated: bool = False, flags: dict | None = None) -> Status:
    """The Status of one trial from its solver outcome and statistics.

    ``saturated``: the channel was clipped (some samples censored); that outranks
    every solver outcome but too little data and a non-finite result. ``flags``: the
    trial's parameter flags; one of :data:`SCALE_PARAMS` "at bound" makes a converged fit
    ``AT_BOUND``.
    """
    if mask.sum() < 3 * n_free:
        return Status.INSUFFICIENT_DATA
    if not (np.all(np.isfinite(u)) and np.isfinite(chi2)):
        return Status.NONFINITE
    if saturated:
        return Status.SATURATED
    if not converged:
        return Status.MAX_STEPS
    if any((flags or {}).get(name) == "at bound" for name in SCALE_PARAMS):
        return Status.AT_BOUND
    if cond > ILL_CONDITIONED:
        return Status.ILL_CONDITIONED
    return Status.CONVERGED
