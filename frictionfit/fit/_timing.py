"""Each movement's own onset and duration in a whole fit: :func:`with_movement_timing`.

The motor's latency jitters from one command to the next (serial link, controller loop),
and so does the movement's duration. Where the recording has the motor's position reads
(:attr:`~frictionfit.fit.measurement_data.MeasurementData.motor`) they give both; elsewhere
both are found from the force at a first fit's optimum: a grid search of each movement's
onset shift, then damped Gauss-Newton steps in every onset and log duration together.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from frictionfit._system import available_cores
from frictionfit.fit.measurement_data import FINE_S, MeasurementData
from frictionfit.fit.result import FitResult
from frictionfit.models import MeasurementModel

__all__ = ["SHIFTS_S", "TIMING_FTOL", "TIMING_STEPS", "TIMING_STEP_MAX",
           "with_movement_timing"]

#: Per-movement onset shifts searched (s): the motor's latency jitters from one command to
#: the next (serial link, controller loop); a shared delay would smear every static peak.
SHIFTS_S = np.arange(-8.0, 8.25, 0.5) * 1e-3
#: Damped Gauss-Newton steps refining every movement's onset and duration together, after
#: the onset search: the movement time jitters too. The data fix one combination of the
#: two sharply (the static peak's time) and the other loosely, so a grid search on one then
#: the other stops on the side of that valley.
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


def with_movement_timing(model: MeasurementModel, items: Sequence[MeasurementData],
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

