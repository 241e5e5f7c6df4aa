"""Whole fits of rubbing measurements: one rig, sensor and contact law per recording and
channel (:func:`fit_whole`); each motion refitted on its own is
:func:`~frictionfit.fit.motions.refit_motions`.

:func:`fit_whole` fits :class:`~frictionfit.models.MeasurementModel` to every item with the
batched Levenberg-Marquardt of :class:`~frictionfit.fit.solver.BatchedLevenbergMarquardt`
in pools of items (:func:`~frictionfit.fit._whole_batch.fit_batch`): a first fit on blocks
merged in pairs (each law of ``"auto"``, the larger from the smaller's optimum; the law by
BIC, :mod:`~frictionfit.fit._law_choice`), then each movement's own latency and duration
(:mod:`~frictionfit.fit._timing`, from the motor's position reads where the recording has
them) and, optionally, the session's rig held, and a second fit on the full grid. The first
``skip_motions`` motions are simulated (they set the contact's state) but not fitted:
closing the fingers leaves an unknown internal force. The public entry is
:func:`frictionfit.fit_recordings`.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Mapping, Sequence

import numpy as np

from frictionfit.fit._law_choice import (
    AUTO_LAWS,
    GROWN_FROM,
    by_bic,
    choice,
    from_optimum,
    held_of,
    in_order,
    origin,
    peak_measured,
)
from frictionfit.fit._timing import with_movement_timing
from frictionfit.fit._whole_batch import (
    FIRST_PASS,
    UNPOLISHED,
    WHOLE_FIT_SOLVER,
    fit_batch,
    with_solver_tolerances,
)
from frictionfit.fit._whole_problem import normal_fn, residual_fn, stack_items
from frictionfit.fit.measurement_data import MeasurementData, measurement_data
from frictionfit.fit.motions import refit_motions
from frictionfit.fit.result import take_trials
from frictionfit.fit.session import (
    CREEP,
    SESSION_RIG,
    SessionRig,
    estimate_session_rigs,
    held_covariance,
    held_profile,
    session_creep,
)
from frictionfit.fit.solver import BatchedLevenbergMarquardt
from frictionfit.fit.whole_result import MeasurementFit
from frictionfit.models import MeasurementModel
from frictionfit.models.measurement import RIG
from frictionfit.segmentation import robust_sd

__all__ = ["AUTO_LAWS", "WHOLE_FIT_SOLVER", "MeasurementData", "fit_measurements",
           "fit_motions", "fit_whole", "measurement_data", "normal_fn", "refit_motions",
           "residual_fn", "stack_items"]

def fit_whole(
    items: Sequence[MeasurementData],
    *,
    model: MeasurementModel | str = "auto",
    solver: BatchedLevenbergMarquardt = WHOLE_FIT_SOLVER,
    rig: str | Mapping[str, SessionRig] = "recording",
    creep: str = "recording",
    timing: str = "movement",
    fix: Mapping[str, float | np.ndarray] | None = None,
    u0: np.ndarray | None = None,
    max_steps: int = 400,
    pool_size: int = 16,
    progress: bool | None = None,
    refit_rig_outliers: bool = True,
) -> MeasurementFit:
    """Fit ``model`` to every item; the arguments as :func:`frictionfit.fit_recordings`
    takes them (``items`` prepared channels). Returns a :class:`MeasurementFit`, one row
    per item (``"auto"``: the BIC of every law in ``bic_table``, NaN where a law was not
    fitted)."""
    _check_rig(rig, items, fix)
    if timing not in ("movement", "rig"):
        raise ValueError(f"timing must be 'movement' or 'rig', not {timing!r}")
    models = ([MeasurementModel(law) for law in AUTO_LAWS] if model == "auto"
              else [MeasurementModel(model) if isinstance(model, str) else model])
    _check_held(fix, items, models)
    if creep not in ("session", "recording"):
        raise ValueError(f"creep must be 'session' or 'recording', not {creep!r}")
    origins = {m.law: origin(m, models) for m in models}
    base = next(origins[m.law] or m for m in models)  # the law fitted from the data
    if u0 is not None and np.shape(u0)[-1] != base.n_params:
        raise ValueError(f"u0 must hold the {base.n_params} parameters of {base.law!r} (the "
                         f"law fitted from the data), not {np.shape(u0)[-1]}")
    start = time.perf_counter()
    run = _Run(solver, rig, timing, dict(max_steps=max_steps, pool_size=pool_size,
                                          progress=progress))
    holds = _Holds()
    if (creep == "session" and set(CREEP) <= set(base.param_names) - set(fix or {})
            and _shared_sessions(items)):
        fix = dict(fix or {}) | holds.creep(items, base, held_of(base, fix, models), u0, run)
    base_fix = held_of(base, fix, models)
    timed, fits = _base_fit(items, base, base_fix, u0, run,
                            held_cov=holds.cov(base, base_fix) if rig == "recording" else None)
    if refit_rig_outliers and rig == "recording" and not set(RIG) & set(base_fix):
        timed, fits = _rig_outliers_refitted(items, timed, fits, base, base_fix, run)
    held, rigs = dict(fix or {}), None
    if rig != "recording":
        sessions = [str(d.session) for d in timed]
        rigs = estimate_session_rigs(sessions, fits) if rig == "session" else dict(rig)
        profile, error = held_profile(sessions, fits, rigs)
        holds.add(fits, error, SESSION_RIG)
        held |= profile
        fits = fit_batch(timed, model=base, u0=np.stack(fits.u), solver=solver,
                         **run.kw, **_broadcast(held_of(base, held, models), len(timed)),
                         held_cov=holds.cov(base, held))
    fits, rows = _other_laws(timed, base, models, origins, fits, run, held, holds)
    first, _, bic = by_bic(models, [fits[m.law] for m in models], [rows[m.law] for m in models])
    first.bic_table = bic if len(models) > 1 else None
    first.session_rigs = rigs
    first.wall_s = time.perf_counter() - start
    return first


class _Run:
    """What every pass of one :func:`fit_whole` shares: the solver, the rig and timing
    options, and the pool's settings (``kw``)."""

    def __init__(self, solver: BatchedLevenbergMarquardt, rig, timing: str, kw: dict):
        self.solver, self.rig, self.timing, self.kw = solver, rig, timing, kw

    @property
    def polished(self) -> bool:
        """Whether a second fit on the full grid polishes a first on merged blocks."""
        return self.rig != "recording" or self.timing == "movement"

    def solver_for(self, polished: bool) -> BatchedLevenbergMarquardt:
        """The solver of a fit that is a final pass (``polished``: it polishes an earlier
        one) or the only one."""
        return self.solver if polished else with_solver_tolerances(self.solver, UNPOLISHED)

    @property
    def first_pass(self) -> BatchedLevenbergMarquardt:
        return with_solver_tolerances(self.solver, FIRST_PASS)


def _shared_sessions(items: Sequence[MeasurementData]) -> bool:
    """Whether some session holds more than one item of a channel (a hold at the session's
    then means something; alone in its session, an item keeps its own values)."""
    keys = [(d.session, d.channel) for d in items if d.session is not None]
    return len(set(keys)) < len(keys)


class _Holds:
    """The values a fit holds at its session's (the finger's creep, the motor's profile), with
    what each adds to the free parameters' covariance: the free fits they were estimated
    from, their error variances and names."""

    def __init__(self):
        self.parts: list[tuple[MeasurementFit, np.ndarray, tuple[str, ...]]] = []

    def add(self, free_fit: MeasurementFit, error: np.ndarray, names: Sequence[str]) -> None:
        self.parts.append((free_fit, error, tuple(names)))

    def creep(self, items: Sequence[MeasurementData], base: MeasurementModel, fix: Mapping,
              u0: np.ndarray | None, run: _Run) -> dict[str, np.ndarray]:
        """The finger's creep of each item's session and channel
        (:func:`~frictionfit.fit.session.session_creep`), from fits of ``base`` with it free
        (the motor's profile per recording); recorded as held."""
        _, free = _base_fit(items, base, fix, u0, _Run(run.solver, "recording", run.timing,
                                                        run.kw))
        values, error = session_creep([str(d.session) for d in items],
                                      [d.channel for d in items], free)
        self.add(free, error, CREEP)
        return values

    def cov(self, model: MeasurementModel, held: Mapping, rows: np.ndarray | None = None
            ) -> np.ndarray | None:
        """What the holds add to ``model``'s free parameters' covariance (of ``rows``), or
        None where nothing is held at a session's."""
        parts = [held_covariance(model, free, error, held, rows, names)
                 for free, error, names in self.parts if set(names) <= set(model.param_names)]
        return sum(parts) if parts else None


def _other_laws(items: Sequence[MeasurementData], base: MeasurementModel,
                models: Sequence[MeasurementModel], origins: dict, base_fit: MeasurementFit,
                run: _Run, held: dict, holds: _Holds) -> tuple[dict, dict]:
    """Each law of ``models`` but ``base`` (fitted from the data: ``base_fit``), from its
    origin's optimum (:data:`GROWN_FROM`, :data:`~frictionfit.fit._law_choice.SHRUNK_FROM`),
    on the items where it can still be chosen. Returns the fits and the items each is of,
    by law."""
    fits, rows = {base.law: base_fit}, {base.law: np.arange(len(items))}
    for m in models:
        if m.law in fits:
            continue
        done = list({d.law: d for d in (*models, base) if d.law in fits}.values())
        fitted, at_rows = [fits[d.law] for d in done], [rows[d.law] for d in done]
        chosen, _ = choice(done, fitted, at_rows)
        can = chosen == [d.law for d in done].index(origins[m.law].law)
        if "f_static_excess" not in m.param_names:
            can &= ~peak_measured(done, fitted, at_rows, len(items))
        rows[m.law] = np.flatnonzero(can)
        start_fit = take_trials(fits[origins[m.law].law], rows[m.law])
        at = [items[i] for i in rows[m.law]]
        fits[m.law] = start_fit if not at else fit_batch(
            at, model=m, u0=from_optimum(m, at, start_fit),
            **_broadcast(held_of(m, held, models), len(items), rows[m.law]),
            solver=run.solver_for(run.polished),
            held_cov=holds.cov(m, held, rows[m.law]),
            restart=m.law not in GROWN_FROM, **run.kw)
    return fits, rows


def _base_fit(items: Sequence[MeasurementData], base: MeasurementModel, fix: Mapping,
              u0: np.ndarray | None, run: _Run, first_fix: Mapping | None = None,
              held_cov: np.ndarray | None = None
              ) -> tuple[list[MeasurementData], MeasurementFit]:
    """The law fitted from the data (:func:`fit_whole`'s first steps): a first fit on
    blocks merged in pairs (``first_fix``: values held in it alone), each movement's timing
    found at its optimum (``"movement"``), and a second fit on the full grid from there
    (``held_cov``: what held values add to its covariance). Returns the items with their
    movements' timing and the fit."""
    again = run.polished
    coarse = [d.halved() for d in items] if again else items
    # a first fit that a second polishes: looser tolerances, and no statement of its own
    first = fit_batch(coarse, model=base, fix=dict(fix) | dict(first_fix or {}), u0=u0,
                      **run.kw, **(dict(solver=run.first_pass, final=False) if again
                                   else dict(solver=run.solver_for(False), held_cov=held_cov)))
    items = (with_movement_timing(base, items, first) if run.timing == "movement"
             else list(items))
    if not again:
        return items, first
    # again on the full grid (for the session's profile, a third fit polishes it)
    return items, fit_batch(items, model=base, u0=np.stack(first.u),
                            **_broadcast(fix, len(items)), **run.kw,
                            **(dict(solver=run.first_pass, final=False)
                               if run.rig != "recording"
                               else dict(solver=run.solver, held_cov=held_cov)))


#: A fit whose movement duration ``ramp`` lies further from the median of its session's fits
#: of the same channel (natural log of the ratio) than this many robust sd of theirs (the
#: median absolute deviation, normal scale), and at least :data:`RIG_OUTLIER_MIN`, is fitted
#: again: from the data's guess with the motor's profile
#: (:data:`~frictionfit.models.measurement.RIG`) held at that session's medians in the first
#: fit, free in the second; the lower BIC is kept. The motor moves alike in every recording
#: of a day, and a soft material's fit can settle in a trap where a slower drive and a
#: stiffer, more slippery contact fit nearly as well.
RIG_OUTLIER_SDS = 3.0
#: ... and the smallest such deviation (a session whose fits agree to 1 %).
RIG_OUTLIER_MIN = 0.1
#: Fewest fits of one session and channel whose median profile such a restart starts from.
MIN_SESSION_FITS = 5


def _rig_starts(items: Sequence[MeasurementData], fit: MeasurementFit) -> dict[int, dict]:
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
                           fit: MeasurementFit, base: MeasurementModel, fix: Mapping, run: _Run
                           ) -> tuple[list[MeasurementData], MeasurementFit]:
    """``timed`` and ``fit`` (:func:`_base_fit` of ``items``) with each fit whose motor
    profile is off its session's (:func:`_rig_starts`) fitted again from the session's
    profile (held in the first fit), where that lowers its BIC."""
    starts = _rig_starts(items, fit)
    if not starts:
        return timed, fit
    rows = np.array(sorted(starts))
    # from the data's guess (u0 None), the held profile overriding its rig
    sub_timed, refit = _base_fit([items[i] for i in rows], base,
                                 _broadcast(fix, len(items), rows)["fix"], None,
                                 _Run(run.solver, "recording", run.timing, run.kw),
                                 first_fix={p: np.array([starts[i][p] for i in rows]) for p in RIG})
    better = np.less(refit.bic, fit.bic[rows])  # False where either is NaN
    chosen = np.zeros(len(items), dtype=np.int64)
    chosen[rows[better]] = 1
    timed = list(timed)
    for k in np.flatnonzero(better):
        timed[rows[k]] = sub_timed[k]
    return timed, in_order([take_trials(fit, np.flatnonzero(chosen == 0)),
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
                             f"profiles given are for {', '.join(sorted(rig)) or 'none'}; a "
                             "session is named within its rig, '<rig>/<session>')")
    if set(SESSION_RIG) & set(fix or {}):
        raise ValueError(f"a session's profile holds {', '.join(SESSION_RIG)}: fix them, or "
                         "leave rig='recording'")


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


def _deprecated(old: str, new: str) -> None:
    warnings.warn(f"{old} is deprecated and will be removed in the next release; use {new}",
                  DeprecationWarning, stacklevel=3)


def fit_measurements(items: Sequence[MeasurementData], **kw) -> MeasurementFit:
    """Deprecated: :func:`frictionfit.fit_recordings` (which also takes prepared items)."""
    _deprecated("fit_measurements", "frictionfit.fit_recordings")
    return fit_whole(items, **kw)


def fit_motions(items: Sequence[MeasurementData], result: MeasurementFit, **kw
                ) -> tuple[MeasurementFit, np.ndarray, np.ndarray]:
    """Deprecated: ``result.per_motion()`` (``items``: ignored, the result keeps its data)."""
    _deprecated("fit_motions", "the fit's .per_motion()")
    motions = refit_motions(result, **kw)
    return motions, motions.item_of, motions.motion_of
