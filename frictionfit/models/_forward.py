"""The contact law's forward-mode Jacobian as one compiled loop (numba).

:func:`~frictionfit.models.stick_slip.contact_force` is a sequential scan; XLA runs its
body as a few dozen small kernels per time step, so ``jax.jacfwd`` of it is bound by their
launches, not by arithmetic. This loop carries the state and its tangents in registers:
the same force and Jacobian (to ~1e-14 relative, tested against ``jax.jacfwd``) 3-10x
faster. It covers what the whole-measurement fits differentiate: one channel of
:class:`~frictionfit.models.MeasurementModel` (the rig's drive, the contact simulated from
rest on a per-sample grid, the sensor), its Jacobian in every physical parameter. The loop
releases the GIL; a batch's rows are shared by one host thread per core (for the XLA
target, which cannot start Python threads, by numba's: :func:`threaded`).
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

__all__ = ["LANES", "channel_jacobian", "channel_values", "timing_normal_equations",
           "weighted_normal_equations"]

#: The law parameters the loop knows, in the order of its ``lanes`` argument.
LANES = ("k", "f_kin", "f_static_excess", "slip_length", "relax_frac", "tau",
         "relax_frac2", "tau2", "damping", "wear")


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _ramp_weight(h):
    """``g = (1 - exp(-h)) / h`` and ``dg/dh`` (series below ``h = 1e-3``)."""
    if h < 1e-3:
        return (1.0 - h / 2.0 + h * h / 6.0 - h * h * h / 24.0,
                -0.5 + h / 3.0 - h * h / 8.0 + h * h * h / 30.0)
    em = -math.expm1(-h)
    return em / h, (math.exp(-h) * h - em) / (h * h)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _maxwell(dt, tau):
    """A Maxwell step's coefficients over ``dt``: ``exp(-h)``, ``g`` and their derivatives'
    parts ``h / tau`` and ``dg/dh h / tau`` in ``tau`` (``h = dt / tau``)."""
    h = dt / tau
    g, dg_dh = _ramp_weight(h)
    return math.exp(-h), g, h / tau, dg_dh * h / tau


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _branches(dt, p, lanes):
    """Both Maxwell branches' :func:`_maxwell` coefficients over ``dt`` (zeros for a branch
    the law lacks)."""
    _, _, _, _, i_rf, i_tau, i_rf2, i_tau2, _, _ = lanes
    none = (0.0, 0.0, 0.0, 0.0)
    return (_maxwell(dt, p[i_tau]) if i_rf >= 0 else none,
            _maxwell(dt, p[i_tau2]) if i_rf2 >= 0 else none)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _constants(x, p, lanes):
    """The law's stiffness ``k``, branch fractions ``rf``, ``rf2`` (0 where absent), the
    second branch's share ``rf2 (1 - rf)`` and half the finger's total travel (mm; 0
    without wear)."""
    i_k, _, _, _, i_rf, _, i_rf2, _, _, i_wear = lanes
    rf = p[i_rf] if i_rf >= 0 else 0.0
    rf2 = p[i_rf2] if i_rf2 >= 0 else 0.0
    half = 0.0
    if i_wear >= 0:
        for i in range(1, x.size):
            half += abs(x[i] - x[i - 1])
        half *= 0.5
    return p[i_k], rf, rf2, rf2 * (1.0 - rf), half


#: The Maxwell steps' coefficients are reused while the sample interval stays within this
#: relative change of the one they were computed for (a uniform grid's intervals differ in
#: their last bits): the force changes by ~1e-12 relative.
_SAME_INTERVAL = 1e-9


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _one(x, xdot, dt, p, lanes, force, jac):
    """Force (n,) and Jacobian (n, m + r) of one simulation, written into the outputs.

    Each sample's scalar state first, then one pass over the tangents (lanes); the terms
    only one lane receives (a parameter's own direct effect) are added around that pass.
    Each exponential is computed only when its argument changes (the Maxwell steps' while
    the interval holds, the slip's while the contact slips, the wear's while the finger
    moves)."""
    n, r = xdot.shape
    m = p.size
    q = m + r
    i_k, i_fk, i_fse, i_sl, i_rf, i_tau, i_rf2, i_tau2, i_damp, i_wear = lanes
    k, rf, rf2, w2_frac, half = _constants(x, p, lanes)
    f_se = p[i_fse] if i_fse >= 0 else 0.0
    damping = p[i_damp] if i_damp >= 0 else 0.0
    scale = math.exp(p[i_wear] * half) if i_wear >= 0 else 1.0
    z = s = w = w2 = travel = 0.0
    decay, direction, interval = 1.0, 1.0, -1.0  # the first sample sets the coefficients
    dz, ds, dw, dw2 = np.zeros(q), np.zeros(q), np.zeros(q), np.zeros(q)
    dstep = np.zeros(q)
    head = np.zeros(q)  # a sliding sample's limit's own terms (times side / k: dzn)
    for i in range(n):
        if abs(dt[i] - interval) > _SAME_INTERVAL * interval:
            interval = dt[i]
            (a1, g1, h1, dg1), (a2, g2, h2, dg2) = _branches(interval, p, lanes)
        step = x[i] - x[i - 1] if i > 0 else 0.0
        for c in range(r):  # the drive's tangents of this step
            dstep[m + c] = xdot[i, c] - xdot[i - 1, c] if i > 0 else 0.0
        moving = step != 0.0
        new_dir = (1.0 if step > 0.0 else -1.0) if moving else direction
        travel += abs(step)
        if moving and new_dir != direction:  # reversal: stuck again
            s = 0.0
            decay = 1.0
            ds[:] = 0.0
        if moving and i_wear >= 0:
            scale = math.exp(p[i_wear] * (half - travel))
        limit = p[i_fk] * scale + f_se * decay
        direction = new_dir
        z_max = limit / k
        z_trial = z + step
        slide = z_trial > z_max or z_trial < -z_max
        side = (1.0 if z_trial > z_max else -1.0) if slide else 0.0
        zn = side * z_max if slide else z_trial
        w_new = zn + a1 * (w - z) - (zn - z) * g1
        w2_new = zn + a2 * (w2 - z) - (zn - z) * g2
        elastic = zn - rf * w_new - w2_frac * w2_new
        rate = damping / dt[i]
        out = jac[i]
        if slide:
            # the limit's tangents: each parameter's own term, and the slip's through ds
            head[i_k] = -limit / k
            head[i_fk] = scale
            if i_wear >= 0:
                head[i_wear] = p[i_fk] * scale * (half - travel)
            slip = 0.0
            if i_fse >= 0:
                length = p[i_sl]
                head[i_fse] = decay
                head[i_sl] = f_se * decay * s / length**2
                slip = f_se * decay / length
            gain = side / k
            for j in range(q):
                dzn = gain * (head[j] - slip * ds[j])
                ds[j] += side * (dz[j] + dstep[j] - dzn)
                dw[j] = dzn + a1 * (dw[j] - dz[j]) - (dzn - dz[j]) * g1
                dw2[j] = dzn + a2 * (dw2[j] - dz[j]) - (dzn - dz[j]) * g2
                out[j] = k * (dzn - rf * dw[j] - w2_frac * dw2[j]) + rate * (dzn - dz[j])
                dz[j] = dzn
            if i_fse >= 0:
                s += abs(z_trial - zn)
                decay = math.exp(-s / p[i_sl])
        else:
            for j in range(q):
                dzn = dz[j] + dstep[j]
                dw[j] = dzn + a1 * (dw[j] - dz[j]) - (dzn - dz[j]) * g1
                dw2[j] = dzn + a2 * (dw2[j] - dz[j]) - (dzn - dz[j]) * g2
                out[j] = k * (dzn - rf * dw[j] - w2_frac * dw2[j]) + rate * (dzn - dz[j])
                dz[j] = dzn
        if i_rf >= 0:
            extra = a1 * h1 * (w - z) + (zn - z) * dg1
            dw[i_tau] += extra
            out[i_tau] -= k * rf * extra
            out[i_rf] -= k * w_new
            w = w_new
        if i_rf2 >= 0:
            extra = a2 * h2 * (w2 - z) + (zn - z) * dg2
            dw2[i_tau2] += extra
            out[i_tau2] -= k * w2_frac * extra
            out[i_rf2] -= k * (1.0 - rf) * w2_new
            out[i_rf] += k * rf2 * w2_new
            w2 = w2_new
        force[i] = k * elastic
        out[i_k] += elastic
        if i_damp >= 0:
            force[i] += rate * (zn - z)
            out[i_damp] += (zn - z) / dt[i]
        z = zn


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _contact(x, dt, p, lanes, force):
    """The force (n,) of :func:`_one` without its tangents (written into ``force``): its
    twin, same steps (change both)."""
    n = x.size
    _, i_fk, i_fse, i_sl, i_rf, i_tau, i_rf2, i_tau2, i_damp, i_wear = lanes
    k, rf, _, w2_frac, half = _constants(x, p, lanes)
    scale = math.exp(p[i_wear] * half) if i_wear >= 0 else 1.0
    z = s = w = w2 = travel = 0.0
    decay, direction, interval = 1.0, 1.0, -1.0  # the first sample sets the coefficients
    for i in range(n):
        if abs(dt[i] - interval) > _SAME_INTERVAL * interval:
            interval = dt[i]
            (a1, g1, _, _), (a2, g2, _, _) = _branches(interval, p, lanes)
        step = x[i] - x[i - 1] if i > 0 else 0.0
        moving = step != 0.0
        new_dir = (1.0 if step > 0.0 else -1.0) if moving else direction
        travel += abs(step)
        if moving and new_dir != direction:  # reversal: stuck again
            s = 0.0
            decay = 1.0
        if moving and i_wear >= 0:
            scale = math.exp(p[i_wear] * (half - travel))
        limit = p[i_fk] * scale
        if i_fse >= 0:
            limit += p[i_fse] * decay
        direction = new_dir
        z_max = limit / k
        z_trial = z + step
        zn = min(max(z_trial, -z_max), z_max)
        if i_fse >= 0 and zn != z_trial:
            s += abs(z_trial - zn)
            decay = math.exp(-s / p[i_sl])
        elastic = zn
        if i_rf >= 0:
            w = zn + a1 * (w - z) - (zn - z) * g1
            elastic -= rf * w
        if i_rf2 >= 0:
            w2 = zn + a2 * (w2 - z) - (zn - z) * g2
            elastic -= w2_frac * w2
        force[i] = k * elastic
        if i_damp >= 0:
            force[i] += p[i_damp] * (zn - z) / dt[i]
        z = zn


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _trapezoid(u, accel):
    """``trapezoid(u, accel)``'s position and velocity, and their derivatives in ``u`` and
    ``accel``: ``(pos, vel, dpos_du, dvel_du, dpos_da, dvel_da)``."""
    if u <= 0.0 or u >= 1.0:
        return (0.0 if u <= 0.0 else 1.0), 0.0, 0.0, 0.0, 0.0, 0.0
    top = 1.0 / (1.0 - accel)
    rate = top / accel
    drate = -(1.0 - 2.0 * accel) * rate * rate
    if u < accel:
        return 0.5 * rate * u * u, rate * u, rate * u, rate, 0.5 * u * u * drate, u * drate
    if u <= 1.0 - accel:
        return (top * (u - 0.5 * accel), top, top, 0.0,
                top * top * (u - 0.5 * accel) - 0.5 * top, top * top)
    w = 1.0 - u
    return (1.0 - 0.5 * rate * w * w, rate * w, rate * w, -rate, -0.5 * w * w * drate,
            w * drate)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _under_way(t, commands):
    """Per sample of increasing times ``t``, the index of the last command given by then
    (the movement under way; -1 before the first)."""
    last, out = -1, np.empty(t.size, np.int64)
    for i in range(t.size):
        while last + 1 < commands.size and commands[last + 1] <= t[i]:
            last += 1
        out[i] = last
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _drive(rig, t, commands, signs, stretch, stroke, x, speed, dx, dspeed):
    """The finger's travel (mm) and velocity (mm/s) at increasing times ``t``, written into
    ``x`` and ``speed``, and their derivatives in ``rig = (delay, ramp, accel)`` into ``dx``
    and ``dspeed`` (n, 3): ``MeasurementModel.finger``'s twin."""
    delay, ramp, accel = rig[0], rig[1], rig[2]
    last = _under_way(t, commands)
    done, counted = 0.0, 0  # the strokes completed before the movement under way
    for i in range(t.size):
        now = max(last[i], 0)
        while counted < now:
            done += signs[counted]
            counted += 1
        sign = signs[now] if last[i] >= 0 else 0.0
        duration = ramp * stretch[now]
        u = (t[i] - commands[now] - delay) / duration
        pos, vel, pos_u, vel_u, pos_a, vel_a = _trapezoid(u, accel)
        x[i] = stroke * (done + sign * pos)
        speed[i] = stroke / duration * sign * vel
        dx[i, 0] = -stroke * sign * pos_u / duration
        dx[i, 1] = -stroke * sign * pos_u * u / ramp
        dx[i, 2] = stroke * sign * pos_a
        dspeed[i, 0] = -stroke * sign * vel_u / duration**2
        dspeed[i, 1] = -stroke * sign * (vel_u * u + vel) / (duration * ramp)
        dspeed[i, 2] = stroke * sign * vel_a / duration


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _intervals(t):
    """Each sample's interval since the previous one (s), the first as the second."""
    dt = np.empty(t.size)
    dt[0] = t[1] - t[0]
    for i in range(1, t.size):
        dt[i] = t[i] - t[i - 1]
    return dt


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _readings(theta, t, x, speed, force, direction, value):
    """The sensor's reading (N) of the contact's ``force`` with the drag at the finger's
    ``speed``, plus its offset, drift and the leak of the travel ``x``, written into
    ``value``: ``MeasurementModel``'s channel from its parts (``theta`` in its order)."""
    m = theta.size - 7
    for i in range(t.size):
        value[i] = (theta[0] + theta[1] * (t[i] - t[0]) + theta[2] * x[i]
                    + direction * (force[i] + theta[3 + m] * speed[i]))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _channel(theta, t, commands, signs, stretch, direction, stroke, lanes, r, value, columns):
    """One channel's value (n,) and Jacobian (n, p) in ``theta`` (sensor, law, drag, rig),
    written into the outputs; ``r``: 3 to push the rig's tangents through the contact, 0 to
    leave the rig's columns 0."""
    n, p = t.size, theta.size
    m = p - 7  # theta: offset, drift, leak, the law's m, drag, delay, ramp, accel
    leak, drag = theta[2], theta[3 + m]
    x, speed = np.empty(n), np.empty(n)
    dx, dspeed = np.empty((n, 3)), np.empty((n, 3))
    _drive(theta[p - 3:], t, commands, signs, stretch, stroke, x, speed, dx, dspeed)
    dt = _intervals(t)
    force, jac = np.empty(n), np.empty((n, m + r))
    _one(x, dx[:, :r], dt, theta[3:3 + m], lanes, force, jac)
    _readings(theta, t, x, speed, force, direction, value)
    for i in range(n):
        out = columns[i]
        out[0], out[1], out[2] = 1.0, t[i] - t[0], x[i]
        for j in range(m):
            out[3 + j] = direction * jac[i, j]
        out[3 + m] = direction * speed[i]
        for c in range(3):
            out[p - 3 + c] = (leak * dx[i, c] + direction * (jac[i, m + c] + drag * dspeed[i, c])
                              if r else 0.0)


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


@numba.njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc", "contract"})
def _dot(a, b):
    """``a . b`` of two contiguous vectors, summed in vector lanes."""
    total = 0.0
    for i in range(a.size):
        total += a[i] * b[i]
    return total


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _weighted_products(columns, value, y, weight, ctc, ctr):
    """``|r|^2 / 2`` of the weighted residual ``r = weight (value - y)``; ``C^T C`` and
    ``C^T r`` of the weighted Jacobian ``C = weight columns`` (n, q) written into ``ctc``,
    ``ctr``: dot products of ``C``'s columns laid out contiguously (no BLAS, whose threads
    would compete with the loop's on calls this small)."""
    n, q = columns.shape
    res, wc = np.empty(n), np.empty((q, n))
    for i in range(n):
        res[i] = weight[i] * (value[i] - y[i])
        for j in range(q):
            wc[j, i] = weight[i] * columns[i, j]
    for j in range(q):
        ctr[j] = _dot(wc[j], res)
        for k in range(j, q):
            ctc[j, k] = ctc[k, j] = _dot(wc[j], wc[k])
    return 0.5 * _dot(res, res)


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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _timing_normal(theta, t, commands, signs, stretch, direction, y, weight, stroke, lanes,
                   ctc, ctr):
    """One channel's weighted cost, and ``ctc``, ``ctr`` in each movement's onset shift
    then log duration factor (written into the outputs)."""
    n, p, c = t.size, theta.size, commands.size
    m = p - 7
    leak, drag, ramp = theta[2], theta[3 + m], theta[p - 2]
    x, speed = np.empty(n), np.empty(n)
    dx, dspeed = np.empty((n, 3)), np.empty((n, 3))
    _drive(theta[p - 3:], t, commands, signs, stretch, stroke, x, speed, dx, dspeed)
    # a shift of the movement under way moves its onset as the delay does; a log duration
    # factor stretches it as ramp d/dramp does
    xdot, sdot = np.zeros((n, 2 * c)), np.zeros((n, 2 * c))
    last = _under_way(t, commands)
    for i in range(n):
        j = last[i]
        if j >= 0:
            xdot[i, j], sdot[i, j] = dx[i, 0], dspeed[i, 0]
            xdot[i, c + j], sdot[i, c + j] = ramp * dx[i, 1], ramp * dspeed[i, 1]
    dt = _intervals(t)
    force, jac = np.empty(n), np.empty((n, m + 2 * c))
    _one(x, xdot, dt, theta[3:3 + m], lanes, force, jac)
    value = np.empty(n)
    _readings(theta, t, x, speed, force, direction, value)
    columns = leak * xdot + direction * (jac[:, m:] + drag * sdot)
    return _weighted_products(columns, value, y, weight, ctc, ctr)


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
