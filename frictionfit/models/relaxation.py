"""Viscoelastic relaxation: the exact exponential-integrator step of a Maxwell branch.

A branch state ``w`` follows the elastic displacement ``z`` with time constant
``tau``: ``dw/dt = (z - w) / tau``. With ``z`` linear between samples the update
is exact, and unconditionally stable for any ``tau`` (below one sample or longer
than the recording).
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["maxwell_coefficients", "maxwell_step"]


def maxwell_coefficients(dt, tau):
    """Decay ``a = exp(-dt/tau)`` and ramp weight ``g = (1 - a) tau/dt`` of one step.

    ``dt`` and ``tau`` in seconds. Constant over a recording, so a scan computes
    them once; ``expm1`` keeps both exact without cancellation for ``tau << dt``
    (``a -> 0``, ``g -> tau/dt``) and ``tau >> dt`` (``a -> 1``, ``g -> 1``).
    """
    h = dt / tau
    g = jnp.where(h < 1e-8, 1.0 - 0.5 * h, -jnp.expm1(-h) / jnp.maximum(h, 1e-300))
    return jnp.exp(-h), g


def maxwell_step(w, z_old, z_new, dt, tau):
    """One exact step of ``dw/dt = (z - w)/tau`` for ``z`` linear from ``z_old`` to ``z_new``.

    ``dt`` and ``tau`` in seconds; ``w``, ``z`` in mm. Uses ``expm1`` so that
    ``tau << dt`` gives ``w -> z`` and ``tau >> dt`` gives ``w`` unchanged, without
    cancellation.
    """
    a, g = maxwell_coefficients(dt, tau)
    return z_new + a * (w - z_old) - (z_new - z_old) * g
