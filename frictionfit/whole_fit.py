"""Fit recordings whole: :func:`fit_recordings`, the one entry point, and its
:class:`WholeFit`.

Like lmfit's ``Model.fit`` returning a ``ModelResult``, :func:`fit_recordings` returns a
result that keeps its models, data and weights and answers the follow-up questions with
nothing passed again: :meth:`~frictionfit.fit.MeasurementFit.report`, ``values`` and
``stderr``, :meth:`~frictionfit.fit.MeasurementFit.predict`,
:meth:`WholeFit.posterior`, :meth:`WholeFit.per_motion` and
:meth:`~frictionfit.fit.MeasurementFit.plot`. Single strokes have their own path,
:func:`frictionfit.fit.fit_trials`, and result, :class:`~frictionfit.fit.FitResult`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from frictionfit.fit.measurement import WHOLE_FIT_SOLVER, fit_whole
from frictionfit.fit.measurement_data import MeasurementData, measurement_data
from frictionfit.fit.session import SessionRig
from frictionfit.fit.solver import BatchedLevenbergMarquardt
from frictionfit.fit.whole_result import MeasurementFit
from frictionfit.models import MeasurementModel
from frictionfit.recording import Recording

if TYPE_CHECKING:
    from frictionfit.uncertainty import Posterior

__all__ = ["WholeFit", "fit_recordings"]

#: The channels a whole fit takes by default: the two fingers' rubbing channels.
RUBBING_CHANNELS = ("thumb_x", "index_x")


@dataclasses.dataclass(repr=False)
class WholeFit(MeasurementFit):
    """The result of :func:`fit_recordings`: a :class:`~frictionfit.fit.MeasurementFit`
    (one row per recording and channel; statistics, data, models, noise) that also samples
    its own posterior."""

    def posterior(self, method: str = "laplace", **kw) -> Posterior:
        """The posterior of every row (:func:`~frictionfit.uncertainty.whole_fit_posterior`:
        ``method`` "laplace", "auto" or "emcee"; ``kw``: its sampler settings and seed).
        The samplers are imported here: a fit alone never loads emcee."""
        from frictionfit.uncertainty import whole_fit_posterior

        return whole_fit_posterior(self, method=method, **kw)

    def per_motion(self, *, max_steps: int = 100, pool_size: int = 16,
                   progress: bool | None = False) -> WholeFit:
        """Each fitted motion refitted on its own, one row per motion (see
        :meth:`~frictionfit.fit.MeasurementFit.per_motion`)."""
        return _as_whole(super().per_motion(max_steps=max_steps, pool_size=pool_size,
                                            progress=progress))


def _as_whole(result: MeasurementFit) -> WholeFit:
    return WholeFit(**{f.name: getattr(result, f.name) for f in dataclasses.fields(result)
                       if f.init})


def _items(recordings, channels: Sequence[str], model, decimate: int,
           skip_motions: int) -> list[MeasurementData]:
    """Each recording's ``channels`` as whole fits take them (prepared items as given)."""
    if isinstance(recordings, (Recording, MeasurementData)):
        recordings = [recordings]
    stroke = model.stroke_mm if isinstance(model, MeasurementModel) else 1.0
    items = []
    for rec in recordings:
        if isinstance(rec, MeasurementData):
            items.append(rec)
            continue
        if not isinstance(rec, Recording):
            raise TypeError(f"fit_recordings takes Recordings (read_recording) or "
                            f"MeasurementData, not {type(rec).__name__}")
        items += [measurement_data(rec, ch, decimate=decimate, skip_motions=skip_motions,
                                   stroke_mm=stroke) for ch in channels]
    if not items:
        raise ValueError("fit_recordings needs at least one recording")
    return items


def fit_recordings(
    recordings: Recording | MeasurementData | Sequence[Recording | MeasurementData], *,
    channels: Sequence[str] = RUBBING_CHANNELS, model: MeasurementModel | str = "auto",
    solver: BatchedLevenbergMarquardt = WHOLE_FIT_SOLVER,
    rig: str | Mapping[str, SessionRig] = "recording", creep: str = "recording",
    timing: str = "movement", fix: Mapping[str, float | np.ndarray] | None = None,
    u0: np.ndarray | None = None, decimate: int = 1, skip_motions: int = 1,
    max_steps: int = 400, pool_size: int = 16, progress: bool | None = None,
    refit_rig_outliers: bool = True,
) -> WholeFit:
    """Fit each recording's channels whole: one rig (the motor's timing), one sensor
    (offset, drift, leak) and one contact law per recording and channel, the law's state
    carried from stroke to stroke.

    Parameters
    ----------
    recordings : Recording, MeasurementData or a sequence of them
        Rubbing recordings (with their ``move`` events), or channels already prepared by
        :func:`~frictionfit.fit.measurement_data` (fitted as given).
    channels : sequence of str
        The channels of each recording to fit (N); default ``thumb_x`` and ``index_x``.
        ValueError naming the recording and channel for one that is absent, not in N or
        without signal.
    model : {"auto", "no_peak2", "relaxation2", "rich", ...} or MeasurementModel
        The law (:data:`frictionfit.models.measurement.LAWS`), or a model with its stroke
        (mm) and priors. ``"auto"``: per row the first of ``no_peak2``, ``relaxation2``,
        ``rich`` whose BIC is within 2 of the best (every law's in ``bic_table``).
    solver : BatchedLevenbergMarquardt
        The final passes' solver and tolerances (``ftol``, ``rtol``, ``atol``); a first pass
        on merged blocks runs at ten times its ``ftol`` and ``rtol``, a fit nothing
        polishes at a tenth.
    rig : "recording", "session" or {session: SessionRig}
        ``"recording"``: the motor's timing fitted per recording and channel (a fit whose
        movement duration stands out of its session's is fitted again from their median
        profile, the better BIC kept, unless ``refit_rig_outliers`` is False).
        ``"session"``: the motor's profile held at each session's median and fitted again,
        its spread carried into the stderrs (``session_rigs``). A mapping: earlier profiles.
    creep : {"recording", "session"}
        ``"recording"``: the finger's creep, the slow relaxation branch's time constant
        ``tau2``, free in every fit. ``"session"``: it is the rig's: fitted free first, then
        held at the median of each session's fits of the same channel (a recording without
        a session, or alone in it, keeps its own), its spread carried into the stderrs.
    timing : {"movement", "rig"}
        ``"movement"``: each movement's own latency and duration (the motor's reads, else
        found from the force at a first optimum); ``"rig"``: one for all.
    fix : mapping, optional
        Name -> physical value (one, or one per row) held (``"auto"``: in the laws that
        have it).
    u0 : ndarray, optional
        Unconstrained start of the law fitted from the data (default: the data's guess).
    decimate, skip_motions : int
        Samples per block while the finger moves; motions simulated but not fitted.
    max_steps, pool_size : int
        Solver steps per pass and row; rows solved together in one pool.
    progress : bool, optional
        A progress bar (default: on a terminal, from 16 rows).

    Returns
    -------
    WholeFit
        One row per recording and channel: values and stderrs in physical units, lmfit-style
        statistics, flags and a status; its data, models and noise, so ``.report()``,
        ``.predict()``, ``.posterior()``, ``.per_motion()`` and ``.plot()`` need no more.

    Examples
    --------
    >>> import frictionfit
    >>> from frictionfit.simulation.measurements import simulate_measurements
    >>> rec, = simulate_measurements([(1, "paper-2", 1)], seed=3)
    >>> fit = frictionfit.fit_recordings(rec, channels=["index_x"], progress=False)
    >>> fit.ids
    ['s1_paper-2_01/index_x']
    """
    items = _items(recordings, channels, model, decimate, skip_motions)
    return _as_whole(fit_whole(items, model=model, solver=solver, rig=rig, creep=creep,
                               timing=timing, fix=fix, u0=u0, max_steps=max_steps,
                               pool_size=pool_size, progress=progress,
                               refit_rig_outliers=refit_rig_outliers))
