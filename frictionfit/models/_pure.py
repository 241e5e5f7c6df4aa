"""The whole-measurement channel's products by JAX's own scan: the compiled loops'
reference twin, run on any JAX backend.

Each function takes the channel ``channel(theta, t, commands, signs, stretch, direction)``
(physical ``theta`` in :attr:`~frictionfit.models.MeasurementModel.param_names`' order,
differentiable in every input) and computes what a compiled loop of
:mod:`frictionfit.models._forward` computes, with ``jax.jacfwd`` for its derivatives: the
fits take these where the loop's XLA target is off (another platform than the CPU, an XLA
FFI layout the target does not know, ``FRICTIONFIT_NATIVE=0``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

__all__ = ["channel_values", "held_channel", "normal_equations", "timing_normal_equations"]


def held_channel(channel: Callable, theta, t, commands, signs, stretch, direction, *,
                 mask: tuple[bool, ...]):
    """The channel with the derivative of ``theta``'s entries where ``mask`` is False, and
    of the data (``t``, the movements, ``direction``), stopped: the compiled loop's
    ``custom_jvp`` twin (N)."""
    theta = jnp.where(jnp.asarray(mask), theta, lax.stop_gradient(theta))
    data = (lax.stop_gradient(a) for a in (t, commands, signs, stretch, direction))
    return channel(theta, *data)


def _products(residual: Callable, x):
    """``(|r|^2 / 2, J^T J, J^T r)`` of ``residual`` at ``x`` (one pass of ``jacfwd``)."""
    jac, r = jax.jacfwd(lambda v: (res := residual(v), res), has_aux=True)(x)
    return 0.5 * r @ r, jac.T @ jac, jac.T @ r


def normal_equations(theta_of: Callable, channel: Callable, u, t, commands, signs, stretch,
                     direction, y, weight, *, free: tuple[int, ...]):
    """``(|r|^2 / 2, J^T J, J^T r)`` of ``r = weight (channel - y)`` in the ``free`` entries
    of unconstrained ``u`` (``theta_of``: ``u`` to the physical ``theta``)."""
    idx = jnp.asarray(free)
    t, commands, signs, stretch, direction, y, weight = (
        jnp.asarray(a) for a in (t, commands, signs, stretch, direction, y, weight))

    def residual(v):
        theta = theta_of(u.at[idx].set(v))
        return weight * (channel(theta, t, commands, signs, stretch, direction) - y)

    return _products(residual, u[idx])


@lru_cache(maxsize=16)
def _values_program(channel: Callable) -> Callable:
    """The channel over a batch's rows, compiled."""
    return jax.jit(jax.vmap(channel))


def _rows(arrays, lead: tuple[int, ...]) -> list[np.ndarray]:
    """Each array (with the leading axes ``lead``) as float64 rows: those axes flattened."""
    rows = math.prod(lead)
    return [np.asarray(a, dtype=np.float64).reshape(rows, *np.shape(a)[len(lead):])
            for a in arrays]


def channel_values(channel: Callable, theta, t, commands, signs, stretch, direction
                   ) -> np.ndarray:
    """The channel (N) for a batch with ``t``'s leading axes, NumPy in and out."""
    lead, n = np.shape(t)[:-1], np.shape(t)[-1]
    rows = _rows((theta, t, commands, signs, stretch, direction), lead)
    return np.asarray(_values_program(channel)(*rows)).reshape(*lead, n)


@lru_cache(maxsize=16)
def _timing_program(channel: Callable) -> Callable:
    """The timing's products of one channel, compiled."""

    def products(theta, t, commands, signs, stretch, direction, y, weight):
        c = commands.size

        def residual(z):
            timed = channel(theta, t, commands + z[:c], signs, stretch * jnp.exp(z[c:]),
                            direction)
            return weight * (timed - y)

        return _products(residual, jnp.zeros(2 * c))

    return jax.jit(products)


def timing_normal_equations(channel: Callable, theta, t, commands, signs, stretch, direction,
                            y, weight) -> tuple[float, np.ndarray, np.ndarray]:
    """``(|r|^2 / 2, J^T J, J^T r)`` of one channel's ``r = weight (channel - y)`` in each
    movement's onset shift (s) then log duration factor, at zero (NumPy in and out)."""
    args = (np.asarray(a, dtype=np.float64) for a in (theta, t, commands, signs, stretch,
                                                        direction, y, weight))
    cost, jtj, jtr = _timing_program(channel)(*args)
    return float(cost), np.asarray(jtj), np.asarray(jtr)
