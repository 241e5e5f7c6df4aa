"""The lateral channels of a rubbing measurement, described by the fitted tangential force.

A finger's lateral channel (``thumb_y``, ``index_y``) carries a share of the tangential
force its rubbing channel (``thumb_x``, ``index_x``) measures: the friction force is not
exactly along the stroke (the textile's weave, the finger's tilt, the sensor's mounting).
Given the whole-measurement fit of the rubbing channel
(:func:`~frictionfit.fit.measurement.fit_measurements`), the lateral channel is fitted as

``y = offset + drift t + leak x + gain F``

with ``F`` (N) the fitted contact force as the rubbing channel sees it (the law with its
drag, signed by the fit's direction; the rubbing sensor's offset, drift and leak left out)
and ``x`` (mm) the fitted finger travel: :data:`LATERAL` are ``offset`` (N), ``drift``
(N/s), ``leak`` (N/mm: the lateral sensor's share of the normal force's change along the
stroke) and ``gain`` (1: lateral over tangential force, signed). The problem is linear:
weighted least squares on the lateral channel's blocks (the weights and the first motion
left out as in the rubbing channel's fit); standard errors as the whole fit's, from the
long-run variance of the residuals' AR(1) noise (:mod:`frictionfit.fit._noise`). What
the lateral law leaves, the lateral stick-slip, is read off its residuals as the
rubbing channel's is: ``slip_noise`` (N,
:func:`~frictionfit.fit.derived.slip_noise`).
"""

from __future__ import annotations

from functools import lru_cache

import jax.numpy as jnp
import numpy as np

from frictionfit.fit._noise import ar1_estimate, long_run_variance
from frictionfit.fit.derived import slip_noise
from frictionfit.fit.measurement_data import MeasurementData
from frictionfit.models import MeasurementModel
from frictionfit.models.measurement import jit_host_loop

__all__ = ["LATERAL", "LATERAL_UNITS", "fit_lateral"]

#: The lateral law's coefficients, in the order of its regressors.
LATERAL = ("offset", "drift", "leak", "gain")
#: Units of the coefficients and of the lateral ``slip_noise``.
LATERAL_UNITS = {"offset": "N", "drift": "N/s", "leak": "N/mm", "gain": "1", "slip_noise": "N"}
#: Fewest fitted blocks for a lateral fit.
MIN_BLOCKS = 20


@lru_cache(maxsize=16)
def _regressors_fn(model: MeasurementModel):
    """Jitted ``(u, t, commands, signs, stretch, direction) -> (F, x)``: the fitted contact
    force as the rubbing channel sees it (N; sensor terms zeroed) and the finger travel (mm)."""
    sensor = jnp.array([model.param_names.index(n) for n in ("offset", "drift", "leak")])

    def regressors(u, t, commands, signs, stretch, direction):
        force = model.predict(u.at[sensor].set(0.0), t, commands, signs, direction,
                              stretch=stretch)
        travel, _ = model.finger(u, t, commands, signs, stretch)
        return force, travel

    return jit_host_loop(regressors)


def fit_lateral(model: MeasurementModel, u: np.ndarray, drive: tuple, direction: float,
                lateral: MeasurementData) -> dict[str, tuple[float, float]]:
    """Name -> ``(value, stderr)`` of :data:`LATERAL` and ``slip_noise`` for one lateral
    channel (module notes).

    ``model``, ``u`` (unconstrained), ``drive`` (the fitted item's ``drive``: ``commands``
    in s with each movement's latency, ``signs``, each movement's ``stretch``) and
    ``direction``: the rubbing channel's fit; ``lateral``: the lateral channel's blocks
    (:func:`~frictionfit.fit.measurement.measurement_data`). NaN where fewer than
    :data:`MIN_BLOCKS` blocks are fitted or the regressors are degenerate.
    """
    t, weight = lateral.t, lateral.weight
    fitted = weight > 0
    nan = {n: (np.nan, np.nan) for n in LATERAL_UNITS}
    if fitted.sum() < MIN_BLOCKS or not np.all(np.isfinite(u)):
        return nan
    commands, signs, stretch = (np.asarray(a, dtype=np.float64) for a in drive)
    force, travel = (np.asarray(a) for a in _regressors_fn(model)(
        jnp.asarray(u), jnp.asarray(t), commands, signs, stretch,
        jnp.asarray(direction, dtype=jnp.float64)))
    a = np.stack([np.ones_like(t), t - t[0], travel, force], axis=1) * weight[:, None]
    b = np.where(fitted, lateral.y, 0.0) * weight
    coef, _, rank, _ = np.linalg.lstsq(a, b, rcond=None)
    if rank < len(LATERAL):
        return nan
    resid = a @ coef - b  # weight (prediction - y), as the whole fit's
    s2 = long_run_variance(*ar1_estimate(resid[None], fitted[None]))[0]
    se = np.sqrt(np.diag(np.linalg.inv(a.T @ a)) * s2)
    out = {n: (float(v), float(e)) for n, v, e in zip(LATERAL, coef, se, strict=True)}
    out["slip_noise"] = slip_noise(resid, t, weight, commands, lateral.noise)
    return out
