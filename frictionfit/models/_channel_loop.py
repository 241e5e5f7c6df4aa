"""One channel of a whole measurement as compiled loops (numba): the rig's drive, the
contact, the sensor's reading, the channel's Jacobian and its weighted products.

Twins of :class:`~frictionfit.models.MeasurementModel`'s channel (``trapezoid``, the
finger's travel, the sensor's terms): a change there must be made here too.
"""

from __future__ import annotations

import numba
import numpy as np

from frictionfit.models._contact_loop import _one


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
