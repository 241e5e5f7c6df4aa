"""The contact law's loop (numba): the force of one simulation, alone or with its
forward-mode tangents.

The state (the contact's elastic stretch, the Maxwell branches, the slip since the last
reversal, the finger's travel) and its tangents are carried in registers from sample to
sample: the compiled twin of :func:`~frictionfit.models.stick_slip.contact_force` that the
whole-measurement fits differentiate.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["LANES"]

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


# The helpers of :func:`_one` are inlined into it (numba IR): the loop compiles as one body.
@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _limit_tangents(head, p, lanes, limit, k, scale, to_half, decay, s):
    """A sliding sample's limit's tangents: each parameter's own term, written into ``head``
    (``to_half``: half the total travel minus the travel so far, mm); returns the factor of
    the slip's tangent (0 without a static peak)."""
    i_k, i_fk, i_fse, i_sl, _, _, _, _, _, i_wear = lanes
    head[i_k] = -limit / k
    head[i_fk] = scale
    if i_wear >= 0:
        head[i_wear] = p[i_fk] * scale * to_half
    if i_fse < 0:
        return 0.0
    length = p[i_sl]
    head[i_fse] = decay
    head[i_sl] = p[i_fse] * decay * s / length**2
    return p[i_fse] * decay / length


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _through_branches(j, dzn, dz, dw, dw2, a1, g1, a2, g2, k, rf, w2_frac, rate):
    """Lane ``j``'s tangent of the stretch, ``dzn``, carried through both Maxwell branches
    (``dz``, ``dw``, ``dw2`` updated in place); returns the lane's tangent of the force."""
    dw[j] = dzn + a1 * (dw[j] - dz[j]) - (dzn - dz[j]) * g1
    dw2[j] = dzn + a2 * (dw2[j] - dz[j]) - (dzn - dz[j]) * g2
    out = k * (dzn - rf * dw[j] - w2_frac * dw2[j]) + rate * (dzn - dz[j])
    dz[j] = dzn
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _in_tau(out, i_tau, a, h, dg, w, z, zn, weight):
    """A Maxwell branch's own term in its time constant: taken off the force's tangent
    ``out[i_tau]`` (``weight``: ``k`` times the branch's share); returns the term, which the
    branch's own tangent in its time constant gains."""
    extra = a * h * (w - z) + (zn - z) * dg
    out[i_tau] -= weight * extra
    return extra


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
            slip = _limit_tangents(head, p, lanes, limit, k, scale, half - travel, decay, s)
            gain = side / k
            for j in range(q):
                dzn = gain * (head[j] - slip * ds[j])
                ds[j] += side * (dz[j] + dstep[j] - dzn)
                out[j] = _through_branches(j, dzn, dz, dw, dw2, a1, g1, a2, g2, k, rf,
                                           w2_frac, rate)
            if i_fse >= 0:
                s += abs(z_trial - zn)
                decay = math.exp(-s / p[i_sl])
        else:
            for j in range(q):
                out[j] = _through_branches(j, dz[j] + dstep[j], dz, dw, dw2, a1, g1, a2, g2,
                                           k, rf, w2_frac, rate)
        if i_rf >= 0:
            dw[i_tau] += _in_tau(out, i_tau, a1, h1, dg1, w, z, zn, k * rf)
            out[i_rf] -= k * w_new
            w = w_new
        if i_rf2 >= 0:
            dw2[i_tau2] += _in_tau(out, i_tau2, a2, h2, dg2, w2, z, zn, k * w2_frac)
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
