"""Pure force laws of the rubbing contact: the drive, and the elastic-plastic slider.

All functions are plain JAX functions of arrays; the family in
:mod:`frictionfit.models.family` names and bounds their parameters.

The contact is a spring of stiffness ``k`` (N/mm) in series with a Coulomb slider
(a play operator): the elastic displacement ``z`` follows the drive until
``k |z|`` reaches the friction limit, then the slider slips. The limit weakens
with accumulated slip ``s`` from a static level to a kinetic one,
``f_kin + f_static_excess * exp(-s / slip_length)``, so a static peak and a
kinetic plateau (stick-slip) come from one differentiable law. Slip history is
reset when the drive reverses. Viscoelastic relaxation (Maxwell branches, exact
exponential integrator) and viscous damping act on ``z``.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from frictionfit.models.relaxation import maxwell_coefficients

__all__ = ["contact_force", "drive", "maxwell_branches", "ramp_shape"]


#: Taylor coefficients of ``sin(x) / x`` and ``cos(x)`` in powers of ``x**2``; on
#: ``|x| <= pi/2`` the first omitted terms are below 2e-18 and 2e-17.
_SIN_TAYLOR = tuple((-1) ** k / math.factorial(2 * k + 1) for k in range(11))
_COS_TAYLOR = tuple((-1) ** k / math.factorial(2 * k) for k in range(12))


def _horner(x2, coefs):
    acc = coefs[-1]
    for c in coefs[-2::-1]:
        acc = acc * x2 + c
    return acc


@jax.custom_jvp
def _sin_half_period(x):
    """``sin(x)`` for ``|x| <= pi/2``, exact to rounding, as a polynomial.

    It replaces XLA's general trigonometry, whose range reduction dominates the drive's
    cost on the CPU. Its derivative is the matching ``cos`` polynomial (differentiating the
    Horner steps instead would cost two operations per step and tangent).
    """
    return x * _horner(x * x, _SIN_TAYLOR)


@_sin_half_period.defjvp
def _sin_half_period_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    x2 = x * x
    return x * _horner(x2, _SIN_TAYLOR), _horner(x2, _COS_TAYLOR) * dx


def ramp_shape(u):
    """Raised-cosine ramp from 0 (u <= 0) to 1 (u >= 1); smooth inside.

    ``0.5 - 0.5 cos(pi v)`` for ``v = clip(u, 0, 1)``, computed as
    ``0.5 + 0.5 sin(pi (v - 1/2))`` on the half period where the polynomial is exact.
    """
    v = jnp.clip(u, 0.0, 1.0)
    return 0.5 + 0.5 * _sin_half_period(jnp.pi * (v - 0.5))


def drive(t, t_out, t_back, delay, ramp, stroke):
    """Finger displacement (mm) of one motion: out at ``t_out``, back at ``t_back``.

    ``t``, ``t_out``, ``t_back``, ``delay`` (motor latency) and ``ramp`` (movement
    duration) in seconds; ``stroke`` in mm.
    """
    out = ramp_shape((t - t_out - delay) / ramp)
    back = ramp_shape((t - t_back - delay) / ramp)
    return stroke * (out - back)


def maxwell_branches(relax_frac, tau, relax_frac2=None, tau2=None) -> tuple[list, list]:
    """Weights (of the instantaneous force) and times (s) of the Maxwell branches in use: the
    second relaxes ``relax_frac2`` of what the first leaves."""
    if relax_frac is None:
        return [], []
    if relax_frac2 is None:
        return [relax_frac], [tau]
    return [relax_frac, relax_frac2 * (1.0 - relax_frac)], [tau, tau2]


def _kinetic_level(f_kin, wear, half_travel, travel, dx):
    """One step of :func:`contact_force`: the kinetic level (N) after a drive step ``dx``
    (mm) and the drive's travel since the start (mm, taken as data): ``f_kin``, worn as
    ``f_kin exp(wear (half_travel - travel))`` unless ``wear`` is None."""
    if wear is None:
        return f_kin, travel
    travel = travel + jax.lax.stop_gradient(jnp.abs(dx))
    return f_kin * jnp.exp(wear * (half_travel - travel)), travel


def contact_force(
    x,
    dt,
    k,
    f_kin,
    f_static_excess=None,
    slip_length=1.0,
    relax_frac=None,
    tau=1.0,
    relax_frac2=None,
    tau2=1.0,
    damping=None,
    wear=None,
    unroll: int = 2,
    state=None,
    return_state: bool = False,
):
    """Tangential force (N) for a drive displacement ``x`` (mm) sampled every ``dt`` s.

    ``dt``: one interval (s), or one per sample (``dt[i] = t[i] - t[i-1]``, ``dt[0]`` any
    positive value) for a non-uniform grid. Parameters (physical units): ``k`` N/mm,
    ``f_kin`` N, ``f_static_excess`` N (static minus kinetic level), ``slip_length`` mm,
    ``relax_frac`` and ``relax_frac2`` (fractions of the instantaneous force that relax;
    their sum is kept below 1), ``tau``/``tau2`` s, ``damping`` N s/mm, ``wear`` 1/mm (the
    kinetic level is ``f_kin exp(wear (L/2 - l))`` after a travel ``l`` of the drive, ``L``
    its whole travel: friction falling as a textile wears, rising where negative; ``f_kin``
    is the level halfway through). An effect whose parameter is ``None`` is left out of the
    recurrence (not computed at all); ``0.0`` gives the same force. Starts at rest with
    ``z = 0``, or from ``state``: the one a previous call left (``return_state=True``:
    ``(force, state)``, so a drive simulated piece by piece, parameters changing between
    pieces, is one continuous history; ``state`` is ``(z, slip, (w per Maxwell branch),
    last x, last direction, travel)``, displacements in mm); every update is exact for any
    interval and stable for any stiffness. ``unroll``: scan unrolling (the default suits
    batched Jacobians on a small CPU). The whole-measurement fits take this
    recurrence's forward-mode Jacobian from a compiled twin
    (:mod:`frictionfit.models._forward`, tested against ``jax.jacfwd`` of this scan): a
    change to the law here must be made there too.
    """
    weakening = f_static_excess is not None
    fracs, taus = maxwell_branches(relax_frac, tau, relax_frac2, tau2)
    per_step = jnp.ndim(dt) > 0  # a non-uniform grid: one interval per sample
    coefs = tuple(maxwell_coefficients(dt, tau_j) for tau_j in taus)
    inv_slip = 1.0 / slip_length
    inv_k = 1.0 / k
    # the travel is taken as data, never differentiated: its derivative in the drive changes
    # the level by wear * dx only, and it made the Jacobian 1.3x dearer
    half_travel = (None if wear is None
                   else 0.5 * jnp.sum(jnp.abs(jnp.diff(jax.lax.stop_gradient(x)))))

    def step(carry, xs):
        x_new, inv_dt, step_coefs = xs if per_step else (xs, 1.0 / dt, coefs)
        branches = [(f, a, g) for f, (a, g) in zip(fracs, step_coefs, strict=True)]
        z, s, ws, x_old, direction, travel = carry
        dx = x_new - x_old
        moving = dx != 0.0
        new_dir = jnp.where(moving, jnp.sign(dx), direction)
        limit, travel = _kinetic_level(f_kin, wear, half_travel, travel, dx)
        if weakening:
            s = jnp.where(moving & (new_dir != direction), 0.0, s)  # reversal: stuck again
            limit = limit + f_static_excess * jnp.exp(-s * inv_slip)
        z_max = limit * inv_k
        z_trial = z + dx
        z_new = jnp.clip(z_trial, -z_max, z_max)
        if weakening:
            s = s + jnp.abs(z_trial - z_new)
        ws = tuple(z_new + a * (w - z) - (z_new - z) * g
                   for w, (_, a, g) in zip(ws, branches, strict=True))
        elastic = z_new - sum(frac * w for w, (frac, _, _) in zip(ws, branches, strict=True))
        force = k * elastic
        if damping is not None:
            force = force + damping * (z_new - z) * inv_dt
        return (z_new, s, ws, x_new, new_dir, travel), force

    zero = jnp.zeros((), dtype=x.dtype)
    init = (zero, zero, (zero,) * len(fracs), x[0], jnp.ones((), dtype=x.dtype), zero)
    xs = (x, 1.0 / dt, coefs) if per_step else x
    last, force = jax.lax.scan(step, init if state is None else state, xs, unroll=unroll)
    return (force, last) if return_state else force
