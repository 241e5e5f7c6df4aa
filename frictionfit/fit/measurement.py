"""Fit whole rubbing measurements: one rig, sensor and material per recording and channel.

:func:`~frictionfit.fit.measurement_data.measurement_data` (also importable from here) puts
one channel of a recording on its time grid as block means. :func:`fit_measurements` fits
:class:`~frictionfit.models.MeasurementModel` to every item with the batched
Levenberg-Marquardt :class:`~frictionfit.fit.solver.BatchedLevenbergMarquardt` in the
pool driver :func:`~frictionfit.fit._optx.solve_pooled` (pools of recordings, slots
refilled): a first fit on blocks merged in pairs (each law of ``"auto"``, the larger from
the smaller's optimum; the law by BIC), then each movement's own latency and duration (from
the motor's position reads where the recording has them, :mod:`frictionfit.fit.motor`) and,
optionally, the session's rig held, and a second fit on the full grid. The first ``skip_motions``
motions are simulated (they set the contact's state) but not fitted: closing the fingers
leaves an unknown internal force.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from frictionfit._system import available_cores
from frictionfit.errors import Status
from frictionfit.fit._noise import RHO_POSTERIOR, lag1_rho
from frictionfit.fit._numerics import map_chunks, scaled_condition
from frictionfit.fit._optx import solve_pooled
from frictionfit.fit._stats import VANISHING, choose, flag_gated, statistics, status_of, widen
from frictionfit.fit.derived import derived_quantities
from frictionfit.fit.measurement_data import FINE_S, MeasurementData, measurement_data
from frictionfit.fit.result import FitResult, concat_results, param_table, take_trials
from frictionfit.fit.session import (
    SESSION_RIG,
    SessionRig,
    estimate_session_rigs,
    held_covariance,
    held_profile,
)
from frictionfit.fit.solver import DATA_FTOL, DATA_RTOL, BatchedLevenbergMarquardt
from frictionfit.models import PARAMS, MeasurementModel
from frictionfit.models.measurement import (
    HOST_LOOP_COMPILER_OPTIONS,
    RIG,
    jit_host_loop,
    to_unconstrained,
)
from frictionfit.models.stick_slip import maxwell_branches
from frictionfit.segmentation import robust_sd

__all__ = ["MeasurementData", "fit_measurements", "fit_motions", "measurement_data",
           "normal_fn", "profile_drops", "residual_fn", "stack_items"]


@lru_cache(maxsize=16)
def residual_fn(model: MeasurementModel, free: tuple[int, ...]):
    """``residual(u_free, data)`` over the ``free`` parameters (the others from the data's
    ``base`` vector): masked residuals, then the priors scaled by the recording's noise sd
    (so the least-squares optimum is the MAP estimate)."""
    free_idx = jnp.asarray(free)
    held = tuple(n for j, n in enumerate(model.param_names) if j not in free)

    def residual(u_free, data):
        y, weight, t, commands, signs, stretch, direction, noise, base = data
        u = base.at[free_idx].set(u_free)
        pred = model.predict(u, t, commands, signs, direction, held, stretch)
        return jnp.concatenate([weight * (pred - y), noise * model.prior_residuals(u)])

    return residual


@lru_cache(maxsize=16)
def normal_fn(model: MeasurementModel, free: tuple[int, ...]):
    """``normal(u_free, data) -> (|r|^2 / 2, J^T J, J^T r)`` of :func:`residual_fn`'s
    residual: the data rows' part from :meth:`MeasurementModel.normal_equations` (on the
    host, no ``(n, p)`` Jacobian in JAX), the priors' by ``jacfwd``."""
    free_idx = jnp.asarray(free)

    def normal(u_free, data):
        y, weight, t, commands, signs, stretch, direction, noise, base = data

        def priors(w):
            return noise * model.prior_residuals(base.at[free_idx].set(w))

        cost, jtj, jtr = model.normal_equations(base.at[free_idx].set(u_free), t, commands,
                                                signs, direction, y, weight, free, stretch)
        rp, jp = priors(u_free), jax.jacfwd(priors)(u_free)
        return cost + 0.5 * rp @ rp, jtj + jp.T @ jp, jtr + jp.T @ rp

    return normal


def stack_items(items: Sequence[MeasurementData], base: np.ndarray):
    """The batch as padded arrays (the solver's per-trial data pytree): past its end an
    item's grid goes on in 1-ms steps with weight 0."""
    n = max(d.y.size for d in items)
    m = max(d.commands.size for d in items)

    def pad(a, size, step=0.0):
        tail = (a[-1] if step else 0.0) + step * np.arange(1, size - a.size + 1)
        return np.concatenate([a, tail])

    return (np.stack([pad(d.y, n) for d in items]), np.stack([pad(d.weight, n) for d in items]),
            np.stack([pad(d.t, n, 1e-3) for d in items]),
            np.stack([pad(d.commands, m) + np.r_[np.zeros(d.commands.size),
                                                 np.full(m - d.commands.size, 1e9)]
                      for d in items]),  # padding commands never come
            np.stack([pad(d.signs, m) for d in items]),
            np.stack([np.r_[d.drive[2], np.ones(m - d.commands.size)] for d in items]),
            np.array([d.direction for d in items]), np.array([d.noise for d in items]), base)


#: The laws ``model="auto"`` chooses from, simplest first.
AUTO_LAWS = ("no_peak2", "relaxation2", "rich")
#: Law -> the smaller law whose optimum it is fitted from (with that law's drive): viscous
#: ``damping`` fitted from the data's guess, or with the others far from their optimum,
#: falls to its lower bound (a log coordinate runs away from where it acts), so ``rich``
#: starts from ``relaxation2``'s optimum with the damping at :data:`DAMPING_START`
#: (docs/decisions.md).
GROWN_FROM = {"rich": "relaxation2"}
#: Law -> the larger law whose optimum it is fitted from where both are chosen from: the
#: law without a static peak is ``relaxation2`` at ``f_static_excess = 0``, so it is fitted
#: only where ``relaxation2``'s peak is not measured (:data:`PEAK_Z`), from that optimum
#: with the peak's mean share over a stroke moved into the kinetic level (docs/decisions.md).
SHRUNK_FROM = {"no_peak2": "relaxation2"}
#: The damping a grown ``rich`` starts from (N s/mm): this fraction of ``f_kin`` over the
#: movement's mean speed (``stroke_mm / ramp``), a viscous force of ~1 % of the kinetic level.
DAMPING_START = 0.01


def fit_measurements(
    items: Sequence[MeasurementData],
    *,
    model: MeasurementModel | str = "auto",
    rig: str | Mapping[str, SessionRig] = "recording",
    timing: str = "movement",
    fix: Mapping[str, float | np.ndarray] | None = None,
    u0: np.ndarray | None = None,
    max_steps: int = 400,
    pool_size: int = 16,
    progress: bool | None = None,
    refit_rig_outliers: bool = True,
) -> FitResult:
    """Fit ``model`` to every item (``progress``: a bar; default: on a terminal, from 16
    items); ``"auto"``: per item, the first law of :data:`AUTO_LAWS`
    (with the same rig and sensor) whose BIC is within ``BIC_TIE`` of the best.

    ``rig="session"``: hold the motor's profile (:data:`~frictionfit.fit.session.SESSION_RIG`)
    at its median over each session's fits on the full grid (every parameter free) and fit
    again (the motor moves the same way in every recording of a day); the spread of the
    session's profiles beyond their fits' errors is carried into the standard errors
    (:mod:`frictionfit.fit.session`); the profiles held are in the result's
    ``session_rigs``. ``rig={session: SessionRig}``: hold profiles estimated before
    (every item's session must have one).
    ``timing="movement"``: shift each movement's command by its own latency deviation and
    stretch its duration by its own factor (both found per movement at the first optimum;
    taken from the motor's position reads where an item has them,
    :attr:`MeasurementData.motor`) and fit again; ``"rig"``: one latency and duration for
    all (but the motor's, where read). ``fix``:
    name -> physical value (one, or one per item) held fixed (``"auto"``: in the laws that
    have the parameter).
    ``u0``: unconstrained starting points of the law fitted from the data (default: the
    data's guess).
    ``max_steps``: per fit and item (a few lab channels crawl along a ridge for 200-400
    steps before they converge).
    One law is fitted from the data (``"auto"``: ``relaxation2``), with a second fit on the
    full grid (the first grid's merged blocks blur a static peak into a fast relaxation);
    with ``rig="recording"`` and ``refit_rig_outliers``, a fit whose movement duration is an
    outlier of its session's is fitted again from the session's motor profile, the lower BIC
    kept (:data:`RIG_OUTLIER_SDS`).
    Each other law is fitted from an optimum on the items where it can still be chosen:
    ``no_peak2`` (:data:`SHRUNK_FROM`) from ``relaxation2``'s where its static peak is not
    measured, then ``rich`` (:data:`GROWN_FROM`) from ``relaxation2``'s where that law is
    chosen.
    Returns a :class:`FitResult` with one row per item (values in physical units,
    lmfit-style statistics, flags of what the data do not determine, a status each; with
    ``"auto"`` the BIC of every law in ``bic_table``, NaN where a law was not fitted).

    The fits use every core by themselves (the compiled contact loop shares a batch's rows
    over them); to run several at once, use processes.
    """
    _check_rig(rig, items, fix)
    if timing not in ("movement", "rig"):
        raise ValueError(f"timing must be 'movement' or 'rig', not {timing!r}")
    models = ([MeasurementModel(law) for law in AUTO_LAWS] if model == "auto"
              else [MeasurementModel(model) if isinstance(model, str) else model])
    _check_held(fix, items, models)
    origin = {m.law: _origin(m, models) for m in models}
    base = next(origin[m.law] or m for m in models)  # the law fitted from the data
    if u0 is not None and np.shape(u0)[-1] != base.n_params:
        raise ValueError(f"u0 must hold the {base.n_params} parameters of {base.law!r} (the "
                         f"law fitted from the data), not {np.shape(u0)[-1]}")
    start = time.perf_counter()
    kw = dict(max_steps=max_steps, pool_size=pool_size, progress=progress)
    base_fix = _held_of(base, fix, models)
    timed, fits = _base_fit(items, base, base_fix, u0, rig, timing, kw)
    if refit_rig_outliers and rig == "recording" and not set(RIG) & set(base_fix):
        timed, fits = _rig_outliers_refitted(items, timed, fits, base, base_fix, timing, kw)
    items, fits = timed, {base.law: fits}
    held, error, free_fit, rigs = dict(fix or {}), None, fits[base.law], None
    if rig != "recording":
        sessions = [str(d.session) for d in items]
        rigs = estimate_session_rigs(sessions, free_fit) if rig == "session" else dict(rig)
        profile, error = held_profile(sessions, free_fit, rigs)
        held |= profile
        fits[base.law] = _fit(items, model=base, u0=np.stack(free_fit.u),
                              tolerances=SECOND_FIT_TOLERANCES, **kw,
                              **_broadcast(_held_of(base, held, models), len(items)),
                              held_cov=held_covariance(base, free_fit, error, held))
    rows = {base.law: np.arange(len(items))}
    for m in models:  # the other laws, from their origin's optimum, where they can be chosen
        if m.law in fits:
            continue
        done = list({d.law: d for d in (*models, base) if d.law in fits}.values())
        fitted = [fits[d.law] for d in done]
        chosen, _ = _choice(done, fitted, [rows[d.law] for d in done])
        can = chosen == [d.law for d in done].index(origin[m.law].law)
        if "f_static_excess" not in m.param_names:
            can &= ~_peak_measured(done, fitted, [rows[d.law] for d in done], len(items))
        rows[m.law] = np.flatnonzero(can)
        start_fit = take_trials(fits[origin[m.law].law], rows[m.law])
        at = [items[i] for i in rows[m.law]]
        fits[m.law] = start_fit if not at else _fit(
            at, model=m, u0=_from_optimum(m, at, start_fit),
            **_broadcast(_held_of(m, held, models), len(items), rows[m.law]),
            tolerances=SECOND_FIT_TOLERANCES if _polished(rig, timing) else None,
            held_cov=None if error is None else held_covariance(
                m, free_fit, error, held, rows[m.law]),
            restart=m.law not in GROWN_FROM, **kw)
    first, chosen, bic = _by_bic(models, [fits[m.law] for m in models],
                                 [rows[m.law] for m in models])
    first.bic_table = bic if len(models) > 1 else None
    first.session_rigs = rigs
    first.wall_s = time.perf_counter() - start
    return first


def _polished(rig, timing: str) -> bool:
    """Whether a second fit on the full grid polishes a first on merged blocks."""
    return rig != "recording" or timing == "movement"


def _base_fit(items: Sequence[MeasurementData], base: MeasurementModel, fix: Mapping,
              u0: np.ndarray | None, rig, timing: str, kw: dict,
              first_fix: Mapping | None = None) -> tuple[list[MeasurementData], FitResult]:
    """The law fitted from the data (:func:`fit_measurements`' first steps): a first fit on
    blocks merged in pairs (``first_fix``: values held in it alone), each movement's timing
    found at its optimum (``"movement"``), and a second fit on the full grid from there.
    Returns the items with their movements' timing and the fit."""
    again = _polished(rig, timing)
    coarse = [d.halved() for d in items] if again else items
    # a first fit that a second polishes: looser tolerances, and no statement of its own
    loose = dict(tolerances=FIRST_FIT_TOLERANCES, final=False) if again else {}
    first = _fit(coarse, model=base, fix=dict(fix) | dict(first_fix or {}), u0=u0, **kw, **loose)
    items = _with_movement_timing(base, items, first) if timing == "movement" else list(items)
    if not again:
        return items, first
    # again on the full grid (for the session's profile, a third fit polishes it)
    return items, _fit(items, model=base, u0=np.stack(first.u), **_broadcast(fix, len(items)),
                       **kw, **(loose if rig != "recording" else
                                dict(tolerances=SECOND_FIT_TOLERANCES)))


#: A fit whose movement duration ``ramp`` lies further from the median of its session's fits
#: of the same channel (natural log of the ratio) than this many robust sd of theirs (the
#: median absolute deviation, normal scale), and at least :data:`RIG_OUTLIER_MIN`, is fitted
#: again: from the data's guess with the motor's profile
#: (:data:`~frictionfit.models.measurement.RIG`) held at that session's medians in the first
#: fit, free in the second; the lower BIC is kept. The motor moves alike in every recording
#: of a day, and a soft material's fit can settle in a trap where a slower drive and a
#: stiffer, more slippery contact fit nearly as well (simulator: ramp +17-32 %, ``k``
#: +30-46 %; docs/decisions.md).
RIG_OUTLIER_SDS = 3.0
#: ... and the smallest such deviation (a session whose fits agree to 1 %).
RIG_OUTLIER_MIN = 0.1
#: Fewest fits of one session and channel whose median profile such a restart starts from.
MIN_SESSION_FITS = 5


def _rig_starts(items: Sequence[MeasurementData], fit: FitResult) -> dict[int, dict]:
    """Item -> the motor's profile (:data:`RIG`, physical) to fit it again from: the medians
    of its session's fits on its channel, for each fit whose ``ramp`` is an outlier among
    them (:data:`RIG_OUTLIER_SDS`; sessions of at least :data:`MIN_SESSION_FITS`)."""
    groups: dict[tuple, list[int]] = {}
    for i, d in enumerate(items):
        if d.session is not None and np.all(np.isfinite(fit.u[i])):
            groups.setdefault((str(d.session), d.channel), []).append(i)
    starts = {}
    for rows in groups.values():
        if len(rows) < MIN_SESSION_FITS:
            continue
        median = {p: float(np.median(fit.values[p].to_numpy()[rows])) for p in RIG}
        log_ramp = np.log(fit.values["ramp"].to_numpy()[rows])
        limit = max(RIG_OUTLIER_MIN,
                    RIG_OUTLIER_SDS * robust_sd(log_ramp))
        for i, off in zip(rows, np.abs(log_ramp - np.log(median["ramp"])) > limit, strict=True):
            if off:
                starts[i] = median
    return starts


def _rig_outliers_refitted(items: Sequence[MeasurementData], timed: list[MeasurementData],
                           fit: FitResult, base: MeasurementModel, fix: Mapping, timing: str,
                           kw: dict) -> tuple[list[MeasurementData], FitResult]:
    """``timed`` and ``fit`` (:func:`_base_fit` of ``items``) with each fit whose motor
    profile is off its session's (:func:`_rig_starts`) fitted again from the session's
    profile (held in the first fit), where that lowers its BIC."""
    starts = _rig_starts(items, fit)
    if not starts:
        return timed, fit
    rows = np.array(sorted(starts))
    # from the data's guess (u0 None), the held profile overriding its rig
    sub_timed, refit = _base_fit([items[i] for i in rows], base,
                                 _broadcast(fix, len(items), rows)["fix"], None, "recording",
                                 timing, kw,
                                 first_fix={p: np.array([starts[i][p] for i in rows]) for p in RIG})
    better = np.less(refit.bic, fit.bic[rows])  # False where either is NaN
    chosen = np.zeros(len(items), dtype=np.int64)
    chosen[rows[better]] = 1
    timed = list(timed)
    for k in np.flatnonzero(better):
        timed[rows[k]] = sub_timed[k]
    return timed, _in_order([take_trials(fit, np.flatnonzero(chosen == 0)),
                             take_trials(refit, np.flatnonzero(better))], chosen)


def _check_rig(rig: str | Mapping[str, SessionRig], items: Sequence[MeasurementData],
               fix: Mapping | None) -> None:
    """Refuse a ``rig`` that is neither a known name nor profiles for every item's session,
    and a held value of what the session's profile holds."""
    if isinstance(rig, str):
        if rig not in ("recording", "session"):
            raise ValueError(f"rig must be 'recording', 'session' or session profiles, "
                             f"not {rig!r}")
        if rig == "recording":
            return
    else:
        missing = sorted({str(d.session) for d in items} - set(rig))
        if missing:
            raise ValueError(f"no motor profile for session(s) {', '.join(missing)} (the "
                             f"profiles given are for {', '.join(sorted(rig)) or 'none'})")
    if set(SESSION_RIG) & set(fix or {}):
        raise ValueError(f"a session's profile holds {', '.join(SESSION_RIG)}: fix them, or "
                         "leave rig='recording'")


def _origin(model: MeasurementModel, models: Sequence[MeasurementModel]
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


def _held_of(model: MeasurementModel, fix: Mapping | None,
             models: Sequence[MeasurementModel]) -> dict:
    """``fix`` without the parameters that ``model`` lacks and another law of ``models`` has:
    a held value applies to the laws that have the parameter (a name no law has stays, to
    be reported)."""
    known = {n for m in models for n in m.param_names}
    return {n: v for n, v in (fix or {}).items() if n in model.param_names or n not in known}


def _check_held(fix: Mapping | None, items: Sequence[MeasurementData],
                models: Sequence[MeasurementModel]) -> None:
    """Refuse a held value that is not finite or lies outside its parameter's bounds in
    ``models`` (it would be pulled inside them, or turn every residual into NaN), naming
    the item."""
    bounds = {n: p for m in models for n, p in zip(m.param_names, m.params, strict=True)}
    for name, value in (fix or {}).items():
        par = bounds.get(name)
        if par is None:
            continue  # an unknown name is refused by the fit, with the law's parameters
        try:
            held = np.broadcast_to(np.asarray(value, dtype=np.float64), (len(items),))
        except ValueError:
            raise ValueError(f"fix[{name!r}] must be one value or one per item "
                             f"({len(items)}), not shape {np.shape(value)}") from None
        bad = np.flatnonzero(~np.isfinite(held) | (held < par.lower) | (held > par.upper))
        if bad.size:
            i = bad[0]
            raise ValueError(f"cannot fix {name} at {held[i]:g} {par.unit} for "
                             f"{items[i].name}/{items[i].channel} ({bad.size} of {len(items)} "
                             f"items): it must be finite and within [{par.lower:g}, "
                             f"{par.upper:g}]")


def _broadcast(fix: Mapping, n: int, rows: np.ndarray | None = None) -> dict:
    """``fix=`` for :func:`_fit`: each held value as one per item (of ``n``), of ``rows``."""
    pick = slice(None) if rows is None else rows
    return {"fix": {name: np.broadcast_to(v, (n,))[pick] for name, v in fix.items()}}


#: A fitted static peak this many standard errors above zero rules out the laws without one
#: for that item, whatever their BIC: the BIC's AR(1) deviance scores the residuals'
#: innovations, and a missing peak is a smooth misfit that a lag-1 coefficient near 1
#: absorbs (docs/decisions.md).
PEAK_Z = 3.0


def _peak_measured(models: list[MeasurementModel], fits: list[FitResult],
                   rows: list[np.ndarray], n: int) -> np.ndarray:
    """Per item (of ``n``), whether a fitted ``f_static_excess`` (one fit of each law in
    ``fits``, of the items ``rows``) stands :data:`PEAK_Z` stderr above zero; a peak on
    its bound (no width: stderr 0) is not measured."""
    peak = np.zeros(n, bool)
    for m, r, at in zip(models, fits, rows, strict=True):
        if "f_static_excess" in m.param_names and r.n_trials:
            value, stderr = (np.asarray(r.values["f_static_excess"]),
                             np.asarray(r.stderr["f_static_excess"]))
            peak[at] |= (stderr > 0) & (value > PEAK_Z * stderr)
    return peak


def _choice(models: list[MeasurementModel], fits: list[FitResult], rows: list[np.ndarray]
            ) -> tuple[np.ndarray, pd.DataFrame]:
    """Per item, the index of the first law whose BIC is within ``BIC_TIE`` of the best (one
    fit of each law in ``fits``, of the items ``rows``), a law without a static peak only
    where no law's peak is measured (:func:`_peak_measured`); and the BIC table (NaN where a
    law was not fitted)."""
    n = max(at.max(initial=-1) for at in rows) + 1
    bic = pd.DataFrame({m.name: np.full(n, np.nan) for m in models})
    for m, r, at in zip(models, fits, rows, strict=True):
        bic.loc[at, m.name] = r.bic
    peak = _peak_measured(models, fits, rows, n)
    eligible = bic.copy()
    for m in models:
        if "f_static_excess" not in m.param_names:
            eligible.loc[peak, m.name] = np.nan
    return np.array([list(bic.columns).index(name) for name in choose(eligible)]), bic


def _by_bic(models: list[MeasurementModel], fits: list[FitResult],
            rows: list[np.ndarray] | None = None) -> tuple[FitResult, np.ndarray, pd.DataFrame]:
    """Per item, the fit of the law :func:`_choice` picks (``rows``: the items each fit is
    of; default all); the law's index per item; the BIC table."""
    rows = rows or [np.arange(fits[0].n_trials)] * len(fits)
    chosen, bic = _choice(models, fits, rows)
    where = [np.searchsorted(at, np.flatnonzero(chosen == j)) for j, at in enumerate(rows)]
    return (_in_order([take_trials(r, w) for r, w in zip(fits, where, strict=True)], chosen),
            chosen, bic)


#: Fewest usable blocks for a motion to be refitted on its own (a motion has ~700).
MIN_MOTION_BLOCKS = 100
#: Parameters of the rig and the sensor: held when single motions are refitted.
SETUP = ("offset", "drift", "leak", *RIG)


def fit_motions(items: Sequence[MeasurementData], result: FitResult, *, max_steps: int = 100,
                pool_size: int = 16, progress: bool | None = False
                ) -> tuple[FitResult, np.ndarray, np.ndarray]:
    """Each fitted motion of each item on its own: the law refitted on the motion's window
    (from its out command to the next one), rig and sensor (:data:`SETUP`) and the kinetic
    level's trend over the measurement (``wear``: one motion cannot tell it from the level)
    held at the whole fit's values, from the whole fit's optimum; the earlier motions are
    still simulated. Each motion's ``f_kin`` is thus its level referred to the whole fit's
    reference point (halfway through the finger's travel). ``progress``: a bar per law
    (None: on a terminal).

    Returns the result (one row per motion) and, per row, the item's index and the motion's
    number: the spread of a parameter over one item's motions says how well one law
    describes the whole measurement.
    """
    rows, item_of, motion_of, parts = [], [], [], []
    for name in dict.fromkeys(result.model):
        model = MeasurementModel(name.removeprefix("measurement-"))
        held = [n for n in (*SETUP, "wear") if n in model.param_names]
        sub, fixed, starts = [], {n: [] for n in held}, []
        for i, d in enumerate(items):
            if result.model[i] != name:
                continue
            driven = d.driven_by(result.drive_input[i])
            outs = driven.commands[driven.signs > 0]
            for m, (a, b) in enumerate(zip(outs, [*outs[1:], np.inf], strict=True)):
                weight = np.where((d.t >= a) & (d.t < b), d.weight, 0.0)
                if np.count_nonzero(weight) < MIN_MOTION_BLOCKS:
                    continue  # the preparatory motion, or one with too few usable blocks
                sub.append(replace(driven, weight=weight))
                starts.append(result.u[i])
                for n in held:
                    fixed[n].append(result.values.at[i, n])
                rows.append(len(rows))
                item_of.append(i)
                motion_of.append(m)
        if sub:
            parts.append(_fit(sub, model=model, fix={n: np.array(v) for n, v in fixed.items()},
                              u0=np.stack(starts), max_steps=max_steps, pool_size=pool_size,
                              progress=progress))
    return concat_results(parts), np.array(item_of), np.array(motion_of)


def _from_optimum(model: MeasurementModel, items: Sequence[MeasurementData], other: FitResult
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


def _in_order(parts: list[FitResult], chosen: np.ndarray) -> FitResult:
    """One result, rows in item order, from per-law results of the rows that chose each law."""
    parts = [p for p in parts if p.n_trials]
    rows = np.concatenate([np.flatnonzero(chosen == j) for j in np.unique(chosen)])
    return take_trials(concat_results(parts), np.argsort(rows))


#: Per-movement onset shifts searched (s): the motor's latency jitters from one command to
#: the next (serial link, controller loop); a shared delay would smear every static peak.
SHIFTS_S = np.arange(-8.0, 8.25, 0.5) * 1e-3
#: Damped Gauss-Newton steps refining every movement's onset and duration together, after
#: the onset search: the movement time jitters too. The data fix one combination of the
#: two sharply (the static peak's time) and the other loosely, so a grid search on one then
#: the other stops on the side of that valley (docs/decisions.md).
TIMING_STEPS = 4
#: Largest change of one movement's onset (s) and log duration in one refining step.
TIMING_STEP_MAX = (0.002, 0.05)
#: ... and the relative cost decrease below which the refining stops.
TIMING_FTOL = 1e-6


def _window_costs(model: MeasurementModel, u: np.ndarray, d: MeasurementData) -> np.ndarray:
    """The weighted residual sum of squares in each command's fine window at ``u``, for every
    common shift of the commands in ``SHIFTS_S``: ``(n_shifts, n_commands)`` (NumPy, by the
    compiled loop)."""
    k, shape = SHIFTS_S.size, (SHIFTS_S.size, d.commands.size)
    value = model.channel(u, np.broadcast_to(d.t, (k, d.t.size)), d.commands + SHIFTS_S[:, None],
                          np.broadcast_to(d.signs, shape), np.ones(shape), np.full(k, d.direction))
    total = np.zeros((k, d.t.size + 1))
    np.cumsum((d.weight * (value - d.y)) ** 2, axis=1, out=total[:, 1:])
    edges = np.searchsorted(d.t, np.stack([d.commands, d.commands + FINE_S]))
    return total[:, edges[1]] - total[:, edges[0]]


def _movement_timing(model: MeasurementModel, u: np.ndarray, d: MeasurementData
                     ) -> tuple[np.ndarray, np.ndarray]:
    """One item's command times and duration factors: the onset shift in :data:`SHIFTS_S`
    that fits each fine window best at ``u``, then up to :data:`TIMING_STEPS`
    Levenberg-Marquardt steps in every movement's onset and log duration together; both
    relative to their median over the fitted movements (``delay`` and ``ramp`` keep the
    typical movement)."""
    u = np.asarray(u, dtype=np.float64)
    cost = _window_costs(model, u, d)
    seen = cost.max(axis=0) > 0  # a window with no fitted block keeps its command
    commands = d.commands + np.where(seen, SHIFTS_S[np.argmin(cost, axis=0)], 0.0)
    stretch = np.ones_like(commands)

    def at(commands, stretch):  # (cost, J^T J, J^T r) at this timing
        return model.timing_normal_equations(u, d.t, commands, d.signs, stretch, d.direction,
                                             d.y, d.weight)

    m, lam = commands.size, 1e-3
    limit = np.repeat(TIMING_STEP_MAX, m)
    here = at(commands, stretch)
    for _ in range(TIMING_STEPS):
        c, jtj, g = here
        diag = np.diagonal(jtj)
        damped = jtj + np.diag(lam * diag + 1e-12 * max(diag.max(), 1e-300))
        z = np.clip(-np.linalg.solve(damped, g), -limit, limit)
        cand = (commands + z[:m], stretch * np.exp(z[m:]))
        there = at(*cand)
        if there[0] <= c:
            (commands, stretch), here, lam = cand, there, lam / 3.0
            if c - there[0] <= TIMING_FTOL * c:
                break
        else:
            lam *= 10.0
    if seen.any():
        commands = commands - np.median((commands - d.commands)[seen])
        stretch = stretch / np.exp(np.median(np.log(stretch[seen])))
    return commands, np.where(seen, stretch, 1.0)


def _with_movement_timing(model: MeasurementModel, items: Sequence[MeasurementData],
                          result: FitResult) -> list[MeasurementData]:
    """Items whose drive carries each movement's own onset and duration: the motor's where
    it was read (kept as it is), else :func:`_movement_timing` at the first fit's optimum
    (items in host threads, one per core)."""
    def timed(i):
        if items[i].motor is not None:
            return items[i]
        commands, stretch = _movement_timing(model, result.u[i], items[i])
        return replace(items[i], commands=commands, stretch=stretch)

    with ThreadPoolExecutor(max_workers=available_cores()) as pool:
        return list(pool.map(timed, range(len(items))))


#: The LM's tolerances for a first fit that a second one polishes: it only has to come near
#: the optimum (docs/decisions.md, "Whole-measurement fits").
FIRST_FIT_TOLERANCES = {"ftol": 1e-4, "xtol": 1e-6}
#: ... and for the second: parameters within a few hundredths of their stderr of the
#: default tolerances' optimum, at 0.8x the steps (docs/decisions.md).
SECOND_FIT_TOLERANCES = {"ftol": 1e-5, "xtol": 1e-7}


def _fit(items, *, model, fix, u0, max_steps, pool_size, progress,
         tolerances: Mapping[str, float] | None = None, final: bool = True,
         restart: bool = True, held_cov: np.ndarray | None = None) -> FitResult:
    """One batched fit of ``items`` with ``fix`` held (see :func:`fit_measurements`);
    ``tolerances``: MINPACK-named tolerances (``ftol``, ``xtol``, ``gtol``; relative) in place
    of those for noisy data (:data:`~frictionfit.fit.solver.DATA_FTOL`, ``DATA_RTOL``).
    ``final=False`` (a fit another one polishes): no derived quantities, and the "trades off"
    flags are not checked along their profiles (a fifth of the CPU time of a whole-fit batch).
    ``restart=False``: no slow branch solved again (:func:`_slow_branch_restarted`; for
    fits started from an optimum where it was). ``held_cov``: per item, the covariance that
    held values' own uncertainty adds to the free parameters
    (:func:`~frictionfit.fit.session.held_covariance`).

    The pools run in one host thread: the contact simulation's Jacobian is a compiled loop
    (:mod:`frictionfit.models._forward`) that shares its rows over the cores itself."""
    fix = dict(fix or {})
    unknown = [n for n in fix if n not in model.param_names]
    if unknown:
        raise ValueError(f"cannot fix {unknown}: parameters are {list(model.param_names)}")
    base = (np.stack([to_unconstrained(model, d.guess) for d in items]) if u0 is None
            else np.array(u0, dtype=np.float64))
    for name, value in fix.items():
        j = model.param_names.index(name)
        base[:, j] = model.params[j].to_unconstrained(np.broadcast_to(value, (len(items),)))
    free = tuple(j for j, n in enumerate(model.param_names) if n not in fix)
    data = stack_items(items, base)
    residual = residual_fn(model, free)
    # MINPACK's names -> the solver's fields: xtol is its rtol, gtol its atol
    field = {"ftol": "ftol", "xtol": "rtol", "gtol": "atol"}
    chosen = {"ftol": DATA_FTOL, "xtol": DATA_RTOL} | dict(tolerances or {})
    solver = BatchedLevenbergMarquardt(normal=normal_fn(model, free),
                                       **{field[k]: v for k, v in chosen.items()})
    branches = not {"relax_frac", "tau", "relax_frac2", "tau2"} & set(fix)

    def solve(start: np.ndarray, rows: np.ndarray, bar=None) -> tuple:
        """The optimum of items ``rows`` from ``start`` (full ``u``, the faster branch put
        first), their status, steps and solver statistics, and which rows were relabelled."""
        u_free, code, steps, stats = solve_pooled(
            solver, residual, start[:, free], jax.tree_util.tree_map(lambda a: a[rows], data),
            pool_size=pool_size, max_steps=max_steps, threads=1,
            progress=None if bar is None else bar.update, solver_stats=True,
            compiler_options=HOST_LOOP_COMPILER_OPTIONS)
        u = start.copy()
        u[:, free] = u_free
        u, relabelled = (_faster_branch_first(model, u) if branches
                         else (u, np.zeros(len(rows), bool)))
        return u, code, steps, stats, relabelled

    # a bar on a terminal only (tqdm's None), for batches long enough to wait for
    show = (None if len(items) >= 16 else True) if progress is None else not progress
    desc = model.law if final else f"{model.law}, first pass"
    with tqdm(total=len(items), desc=desc, unit="rec", disable=show) as bar:
        u, code, steps, at_solution, again = solve(base, np.arange(len(items)), bar)
    if branches and restart:
        again |= _slow_branch_restarted(model, items, solve, u, code, steps, at_solution)
    resid, jtj = _at_optimum(model, free, u[:, free], data, at_solution["jtj"], again)
    weight = data[1]
    mask = weight > 0
    # AR(1) residuals carry fewer independent points than blocks: the covariance grows by
    # (1 + rho) / (1 - rho), the variance of a mean of correlated noise.
    rho = np.clip(lag1_rho(resid, mask), *RHO_POSTERIOR)
    inflation = (1 + rho) / (1 - rho)
    stats = statistics(model, u, resid, jtj / inflation[:, None, None], mask, free, tuple(fix))
    block_var = stats["redchi"] * inflation
    if final:
        _ridges_checked(model, free, u, stats, data, block_var)
    if held_cov is not None:
        widen(model, u, stats, free, held_cov)
    y_bar = np.sum(weight**2 * data[0], axis=1) / np.maximum(np.sum(weight**2, axis=1), 1e-300)
    ss_tot = np.sum(weight**2 * (data[0] - y_bar[:, None]) ** 2, axis=1)
    r2 = 1.0 - stats["chi2"] / np.where(ss_tot > 0, ss_tot, np.nan)
    names = [model.param_names[j] for j in free]
    cond = np.array([_cond_inside(jtj[i], [stats["flags"][i].get(n) not in VANISHING
                                           for n in names])
                     for i in range(len(items))])
    status = np.array([status_of(len(free), code[i] == Status.CONVERGED, u[i], stats["chi2"][i],
                                 cond[i], mask[i], saturated=items[i].clipped > 0,
                                 flags=stats["flags"][i])
                       for i in range(len(items))])
    return FitResult(
        model=[model.name] * len(items), values=param_table(stats["values"]),
        stderr=param_table(stats["stderr"]),
        flags=stats["flags"], status=status.astype(np.int64), chi2=stats["chi2"],
        redchi=stats["redchi"], aic=stats["aic"], bic=stats["bic"], r2=r2, cond=cond,
        n_steps=steps, ndata=stats["ndata"], nvarys=stats["nvarys"], u=list(u),
        direction=data[6], drive="measurement",
        drive_input=[d.drive for d in items],
        init=[_physical_init(model, d.guess) for d in items],
        correl=stats["correl"], cov=list(stats["cov"]), block_var=block_var,
        stroke_mm=model.stroke_mm,
        priors=_prior_dict(model),
        derived=(derived_quantities(model, free, u, stats["cov"], resid, items, data[6])
                 if final else None))


#: Smallest drop of the log-posterior 2 sd out on either side of a parameter's Gaussian
#: profile line (its covariance column; the Gaussian predicts a drop of exactly 2) for a
#: parameter that trades off with another to keep its stderr as a (conservative) interval.
PROFILE_MIN_DROP = 1.0


@lru_cache(maxsize=16)
def _cost_fn(model: MeasurementModel, free: tuple[int, ...]):
    """Jitted ``(points, data) -> sum of squared residuals`` (priors included) at each of
    ``points`` (m, p_free) of one item."""
    residual = residual_fn(model, free)
    return jit_host_loop(lambda points, data: jax.vmap(
        lambda w: jnp.sum(residual(w, data) ** 2))(points))


def profile_drops(model: MeasurementModel, free: tuple[int, ...], u_free: np.ndarray,
                  cov: np.ndarray, data, s2: np.ndarray, rows) -> np.ndarray:
    """Per item of ``rows``, ``(len(rows), 2, q)``: the fall of the log-density
    ``-|residual|^2 / (2 s2)`` from ``u_free`` to 2 sd out on the + and - side of each free
    parameter's Gaussian profile line (its column of ``cov``, finite); a Gaussian falls by
    exactly 2. ``data``: the stacked items (:func:`stack_items`); ``s2``: per item, the
    variance scale of ``cov``. NaN where the residual is not finite."""
    cost = _cost_fn(model, free)
    q = len(free)
    out = np.full((len(rows), 2, q), np.nan)
    for k, i in enumerate(rows):
        line = (cov[i] / np.sqrt(np.maximum(np.diag(cov[i]), 1e-300))).T  # row j: j's line
        points = np.concatenate([u_free[i][None], u_free[i] + 2 * line, u_free[i] - 2 * line])
        c = np.asarray(cost(points, jax.tree_util.tree_map(lambda a, i=i: a[i], data)))
        out[k] = ((c[1:] - c[0]) / (2 * s2[i])).reshape(2, q)
    return out


def _ridges_checked(model: MeasurementModel, free: tuple[int, ...], u: np.ndarray,
                    stats: dict, data, s2: np.ndarray) -> None:
    """Lift (in place) each "trades off with" flag whose parameter's log-posterior falls by
    at least :data:`PROFILE_MIN_DROP` 2 sd out on both sides of its profile line
    (:func:`profile_drops`): the posterior is then no wider there than the Gaussian (it is
    often narrower: the drops grow faster than the square along a curved ridge), and the
    standard error is an interval that does not overstate what the data say. Along a flat
    or one-sided ridge (a relaxation time far beyond the recording) the drop stays small
    and the flag stays. ``s2``: per item, the variance scale of ``cov`` (the reduced
    chi-square times the AR(1) inflation)."""
    names = [model.param_names[j] for j in free]
    rows = [i for i, flags in enumerate(stats["flags"])
            if any(flags.get(n, "").startswith("trades off") for n in names)
            and np.all(np.isfinite(stats["cov"][i]))]
    drops = profile_drops(model, free, u[:, list(free)], stats["cov"], data, s2, rows)
    for i, drop in zip(rows, drops.min(axis=1), strict=True):
        flags = stats["flags"][i]
        for name, d in zip(names, drop, strict=True):
            if flags.get(name, "").startswith("trades off") and d >= PROFILE_MIN_DROP:
                del flags[name]
        flag_gated(flags, stats["values"][i], stats["stderr"][i])


def _cond_inside(jtj: np.ndarray, inside: list[bool]) -> float:
    """Condition number of the column-scaled ``J^T J`` over the parameters ``inside``.

    A parameter whose column vanishes (:data:`VANISHING`) makes ``J^T J`` singular however
    well the others are determined; it is reported with its flag, and the conditioning that
    matters is the others'.
    """
    a = jtj[np.ix_(np.flatnonzero(inside), np.flatnonzero(inside))]
    return float(scaled_condition(a)) if np.all(np.isfinite(a)) else np.inf


def _physical_init(model: MeasurementModel, guess: dict) -> dict:
    """The starting point in physical units, every parameter (defaults where not guessed)."""
    return {p.name: float(guess.get(p.name, p.default)) for p in model.params}


def _prior_dict(model: MeasurementModel) -> dict | None:
    return None if model.priors is None else dict(model.prior_table)


#: Fraction of the force a slow Maxwell branch pinned at its largest fraction is restarted
#: from (its time: the median interval between commands, one hold): see
#: :func:`_slow_branch_restarted`.
RESTART_FRACTION = 0.2


def _slow_branch_restarted(model: MeasurementModel, items: Sequence[MeasurementData], solve,
                           u: np.ndarray, code: np.ndarray, steps: np.ndarray,
                           at_solution: dict) -> np.ndarray:
    """Solve again each item whose slow branch ended at the largest fraction (``relax_frac2``
    at its upper bound, ``tau2`` seconds long), from the branch at :data:`RESTART_FRACTION`
    relaxing over one hold, and keep the optimum of lower cost (priors included); ``u``,
    ``code``, ``steps`` and the solver's statistics updated in place. Returns which items
    changed. The logistic map is flat at the bound, so a solver that runs there does not
    come back, though a weaker, faster branch often fits better (docs/decisions.md)."""
    names = model.param_names
    if "relax_frac2" not in names:
        return np.zeros(len(u), bool)
    j_frac, j_time = names.index("relax_frac2"), names.index("tau2")
    frac = PARAMS["relax_frac2"]
    rows = np.flatnonzero((u[:, j_frac] > 0) & frac.at_bound(frac.to_physical(u[:, j_frac])))
    changed = np.zeros(len(u), bool)
    if rows.size == 0:
        return changed
    start = u[rows].copy()
    start[:, j_frac] = frac.to_unconstrained(RESTART_FRACTION)
    hold = np.array([np.median(np.diff(items[i].commands)) for i in rows])
    slow = PARAMS["tau2"]
    start[:, j_time] = slow.to_unconstrained(np.where(hold > 0, hold, slow.default))
    new_u, new_code, new_steps, new_stats, _ = solve(start, rows)
    better = new_stats["cost"] < at_solution["cost"][rows]
    keep = rows[better]
    u[keep], code[keep] = new_u[better], new_code[better]
    steps[rows] += new_steps
    for name, value in at_solution.items():
        value[keep] = new_stats[name][better]
    changed[keep] = True
    return changed


def _faster_branch_first(model: MeasurementModel, u: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Relabel the two Maxwell branches where ``tau > tau2`` (the same force: branch weights
    ``relax_frac`` and ``relax_frac2 (1 - relax_frac)`` swapped), so ``tau`` is the faster;
    and which rows were relabelled."""
    names = model.param_names
    if "tau2" not in names:
        return u, np.zeros(u.shape[0], bool)
    v = model.physical(u)
    swap = v["tau"] > v["tau2"]
    (w1, w2), _ = maxwell_branches(v["relax_frac"], v["tau"], v["relax_frac2"], v["tau2"])
    new = {"tau": v["tau2"], "tau2": v["tau"], "relax_frac": w2,
           "relax_frac2": w1 / np.maximum(1.0 - w2, 1e-12)}
    u = u.copy()
    for name, value in new.items():
        j = names.index(name)
        u[swap, j] = PARAMS[name].to_unconstrained(value[swap])
    return u, np.asarray(swap)


@lru_cache(maxsize=16)
def _jacobian_fn(model: MeasurementModel, free: tuple[int, ...]):
    """Jitted ``(u_free, data) -> J^T J`` (with the prior rows) of one item."""
    normal = normal_fn(model, free)
    return jit_host_loop(lambda u_free, data: normal(u_free, data)[1])


@lru_cache(maxsize=16)
def _residuals_fn(model: MeasurementModel, free: tuple[int, ...]):
    """Jitted, vmapped ``(u_free, data) -> data residuals`` of a chunk of items."""
    residual = residual_fn(model, free)
    return jit_host_loop(jax.vmap(lambda w, data: residual(w, data)[: data[0].shape[-1]]))


#: Items per call where the residuals at the solutions are evaluated.
RESIDUAL_CHUNK = 16


def _at_optimum(model: MeasurementModel, free: tuple[int, ...], u_free, data,
                jtj: np.ndarray, again: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Data residuals and ``J^T J`` at ``u_free``: ``J^T J`` as the solver left it at its
    solution, computed again only for the rows in ``again`` (relabelled after the fit) or
    where it is not finite; the residuals in chunks of :data:`RESIDUAL_CHUNK` items."""
    resid = map_chunks(_residuals_fn(model, free), (u_free, data), RESIDUAL_CHUNK)
    jtj = np.array(jtj, dtype=np.float64)
    one = _jacobian_fn(model, free)
    for i in np.flatnonzero(again | ~np.all(np.isfinite(jtj), axis=(1, 2))):
        jtj[i] = np.asarray(one(u_free[i], jax.tree_util.tree_map(lambda a, i=i: a[i], data)))
    return resid, jtj


