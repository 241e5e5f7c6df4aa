"""The whole-measurement channel's compiled loops (numba) over a batch, NumPy in and out.

:func:`~frictionfit.models.stick_slip.contact_force` is a sequential scan; XLA runs its
body as a few dozen small kernels per time step, so ``jax.jacfwd`` of it is bound by their
launches, not by arithmetic. The loops (:mod:`frictionfit.models._contact_loop`, the
contact; :mod:`frictionfit.models._channel_loop`, the drive, sensor and one channel) carry
the state and its tangents in registers: the same force and Jacobian (to ~1e-14 relative,
tested against ``jax.jacfwd``), without the launches. They cover what the whole-measurement fits
differentiate: one channel of :class:`~frictionfit.models.MeasurementModel`, its Jacobian
in every physical parameter. The loops release the GIL; a batch's rows are shared by one
host thread per core (for the XLA target, which cannot start Python threads, by numba's:
:func:`threaded`).
"""

from __future__ import annotations

import math
import os
import types
from concurrent.futures import ThreadPoolExecutor
from functools import cache

import numba
import numpy as np

from frictionfit._system import available_cores
from frictionfit.models._channel_loop import (
    _channel,
    _drive,
    _intervals,
    _readings,
    _timing_normal,
    _weighted_products,
)
from frictionfit.models._contact_loop import LANES, _contact

__all__ = ["LANES", "channel_jacobian", "channel_values", "timing_normal_equations",
           "weighted_normal_equations"]

@numba.njit(cache=True, nogil=True, error_model="numpy")
def _part(rows, parts, i):
    """Rows ``[lo, hi)`` of part ``i`` of ``parts`` nearly equal contiguous parts."""
    return i * rows // parts, (i + 1) * rows // parts


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _batch_value(theta, t, commands, signs, stretch, direction, stroke, lanes, threads,
                 value):
    """Each row's channel (:func:`_channel`'s value, no Jacobian) written into ``value``;
    the rows in ``threads`` parts (run in parallel by :func:`threaded`'s twin)."""
    rows, n, p = t.shape[0], t.shape[1], theta.shape[1]
    m = p - 7
    parts = max(1, min(rows, threads))
    for part in numba.prange(parts):
        x, speed, force = np.empty(n), np.empty(n), np.empty(n)
        dx, dspeed = np.empty((n, 3)), np.empty((n, 3))
        lo, hi = _part(rows, parts, part)
        for b in range(lo, hi):
            th, tb = theta[b], t[b]
            _drive(th[p - 3:], tb, commands[b], signs[b], stretch[b], stroke, x, speed, dx,
                   dspeed)
            _contact(x, _intervals(tb), th[3:3 + m], lanes, force)
            _readings(th, tb, x, speed, force, direction[b], value[b])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _batch(theta, t, commands, signs, stretch, direction, stroke, lanes, r, threads, value,
           columns):
    """Each row's channel and Jacobian (:func:`_channel`); the rows in ``threads`` parts."""
    rows = t.shape[0]
    parts = max(1, min(rows, threads))
    for part in numba.prange(parts):
        lo, hi = _part(rows, parts, part)
        for b in range(lo, hi):
            _channel(theta[b], t[b], commands[b], signs[b], stretch[b], direction[b], stroke,
                     lanes, r, value[b], columns[b])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _batch_normal(theta, t, commands, signs, stretch, direction, y, weight, stroke, lanes, r,
                  threads, cost, ctc, ctr):
    """Each row's :func:`_weighted_products` of its channel and Jacobian; the rows in
    ``threads`` parts."""
    rows, n, p = t.shape[0], t.shape[1], theta.shape[1]
    parts = max(1, min(rows, threads))
    for part in numba.prange(parts):
        value, columns = np.empty(n), np.empty((n, p))
        lo, hi = _part(rows, parts, part)
        for b in range(lo, hi):
            _channel(theta[b], t[b], commands[b], signs[b], stretch[b], direction[b], stroke,
                     lanes, r, value, columns)
            cost[b] = _weighted_products(columns, value, y[b], weight[b], ctc[b], ctr[b])


def timing_normal_equations(theta: np.ndarray, t: np.ndarray, commands: np.ndarray,
                            signs: np.ndarray, stretch: np.ndarray, direction: float,
                            y: np.ndarray, weight: np.ndarray, *, names: tuple[str, ...],
                            stroke_mm: float) -> tuple[float, np.ndarray, np.ndarray]:
    """``(|r|^2 / 2, J^T J, J^T r)`` of one channel's weighted residual ``r = weight
    (channel - y)`` in each movement's onset shift (s) then log duration factor, at zero
    (arguments as for :func:`channel_jacobian`, one channel): the movement timing's step."""
    theta, t, commands, signs, stretch, y, weight = (
        np.ascontiguousarray(a, dtype=np.float64)
        for a in (theta, t, commands, signs, stretch, y, weight))
    q = 2 * commands.size
    ctc, ctr = np.empty((q, q)), np.empty(q)
    cost = _timing_normal(theta, t, commands, signs, stretch, float(direction), y, weight,
                          stroke_mm, _lanes(tuple(names)), ctc, ctr)
    return cost, ctc, ctr


def _on_rows(kernel, inputs: list[np.ndarray], consts: tuple, outputs: list[np.ndarray]):
    """``kernel(*inputs, *consts, 1, *outputs)`` over a batch's rows (the leading axis of
    every input and output), shared by one host thread per core, each writing its own (no
    threading layer of numba's: safe in threads and in a forked process alike)."""
    rows = inputs[0].shape[0]
    parts = np.array_split(np.arange(rows), max(1, min(rows, available_cores())))
    if len(parts) == 1:
        kernel(*inputs, *consts, 1, *outputs)
        return
    list(_pool().map(
        lambda i: kernel(*(a[i] for a in inputs), *consts, 1, *(o[i] for o in outputs)),
        [slice(q[0], q[-1] + 1) for q in parts]))


def _flat(arrays, lead: tuple[int, ...]) -> list[np.ndarray]:
    """Each array as float64 rows: its ``lead`` axes flattened into one."""
    rows = math.prod(lead)
    return [np.ascontiguousarray(a, dtype=np.float64).reshape(rows, *np.shape(a)[len(lead):])
            for a in arrays]


def channel_values(theta: np.ndarray, t: np.ndarray, commands: np.ndarray, signs: np.ndarray,
                   stretch: np.ndarray, direction: np.ndarray, *, names: tuple[str, ...],
                   stroke_mm: float) -> np.ndarray:
    """One channel of ``MeasurementModel`` (N), for a batch (arguments as for
    :func:`channel_jacobian`): its value alone, several times faster than with the
    Jacobian. Shape ``(..., n)``."""
    lead, n = t.shape[:-1], t.shape[-1]
    inputs = _flat((theta, t, commands, signs, stretch, direction), lead)
    value = np.empty((len(inputs[0]), n))
    _on_rows(_batch_value, inputs, (stroke_mm, _lanes(tuple(names))), [value])
    return value.reshape(*lead, n)


def channel_jacobian(theta: np.ndarray, t: np.ndarray, commands: np.ndarray,
                     signs: np.ndarray, stretch: np.ndarray, direction: np.ndarray, *,
                     names: tuple[str, ...], stroke_mm: float, rig_columns: bool
                     ) -> tuple[np.ndarray, np.ndarray]:
    """One channel of ``MeasurementModel`` (N) and its Jacobian, for a batch.

    ``theta`` (..., p): physical values in the model's ``param_names`` order (sensor, the
    law ``names``, drag, rig); ``t`` (..., n): increasing times (s); ``commands``,
    ``signs``, ``stretch`` (..., c): the movements; ``direction`` (...): the channel's sign.
    Returns the channel (..., n) and its derivative in each of ``theta`` (..., n, p);
    ``rig_columns=False``: the rig's columns left 0 (the drive's tangents not pushed
    through the contact: a fit that holds the rig).
    """
    lead, (n, p) = t.shape[:-1], (t.shape[-1], theta.shape[-1])
    inputs = _flat((theta, t, commands, signs, stretch, direction), lead)
    value, columns = np.empty((len(inputs[0]), n)), np.empty((len(inputs[0]), n, p))
    _on_rows(_batch, inputs, (stroke_mm, _lanes(tuple(names)), 3 if rig_columns else 0),
             [value, columns])
    return value.reshape(*lead, n), columns.reshape(*lead, n, p)


def weighted_normal_equations(theta: np.ndarray, t: np.ndarray, commands: np.ndarray,
                              signs: np.ndarray, stretch: np.ndarray, direction: np.ndarray,
                              y: np.ndarray, weight: np.ndarray, *, names: tuple[str, ...],
                              stroke_mm: float, rig_columns: bool
                              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(|r|^2 / 2, C^T C, C^T r)`` of the weighted residual ``r = weight (channel - y)``
    and its Jacobian ``C`` in ``theta``, for a batch (arguments as for
    :func:`channel_jacobian`; ``y``, ``weight`` (..., n)): the products summed sample by
    sample as the loop goes, no ``(n, p)`` Jacobian kept. Shapes ``(...)``, ``(..., p,
    p)``, ``(..., p)``."""
    lead, p = t.shape[:-1], theta.shape[-1]
    inputs = _flat((theta, t, commands, signs, stretch, direction, y, weight), lead)
    rows = len(inputs[0])
    cost, ctc, ctr = np.empty(rows), np.empty((rows, p, p)), np.empty((rows, p))
    _on_rows(_batch_normal, inputs, (stroke_mm, _lanes(tuple(names)), 3 if rig_columns else 0),
             [cost, ctc, ctr])
    return cost.reshape(lead), ctc.reshape(*lead, p, p), ctr.reshape(*lead, p)


@cache
def _lanes(names: tuple[str, ...]) -> np.ndarray:
    """Where each of :data:`LANES` sits in ``names`` (-1: absent)."""
    return np.array([names.index(nm) if nm in names else -1 for nm in LANES], np.int64)


@cache
def _pool() -> ThreadPoolExecutor:
    """The NumPy callers' Python threads, one per core (:func:`threads` counts numba's)."""
    return ThreadPoolExecutor(available_cores(), thread_name_prefix="frictionfit-contact")


# a forked process has none of its parent's threads: it starts a pool of its own
os.register_at_fork(after_in_child=_pool.cache_clear)


def threaded(kernel):
    """A batch loop compiled again with its parts run in parallel by numba's threads
    (``prange``), for callers that cannot start threads themselves (the XLA target); a
    function of its own name, so that numba's cache keeps both."""
    f = kernel.py_func
    twin = types.FunctionType(f.__code__, f.__globals__, f"{f.__name__}_threaded")
    twin.__qualname__ = twin.__name__
    return numba.njit(cache=True, nogil=True, error_model="numpy", parallel=True)(twin)


@numba.njit(cache=True, parallel=True)
def _started(n):
    """A loop over ``n`` that starts numba's threads (and so picks its threading layer)."""
    total = 0
    for i in numba.prange(n):
        total += i
    return total


@cache
def threads() -> int:
    """Threads a :func:`threaded` loop may use: one per core where numba's threading layer
    lets several callers start loops at once (OpenMP, TBB: XLA calls the target from its own
    threads), else 1 (its ``workqueue`` layer must not be entered by two threads at once:
    the serial loops are used instead)."""
    _started(1)
    return available_cores() if numba.threading_layer() in ("omp", "tbb") else 1
