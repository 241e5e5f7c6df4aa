"""What a whole-measurement fit says beyond its parameters: held and peak forces, stick-slip.

Five quantities per fitted channel, each with a standard error (``derived`` of a
:class:`~frictionfit.fit.result.FitResult` from
:func:`~frictionfit.fit.measurement.fit_measurements`):

- ``f_held`` (N): half the step between the fitted channel's held levels at the two ends of
  the stroke, ``HOLD_S`` after a movement that followed an opposite one: the law's held
  force (what friction keeps of the load once the fingers stand still) plus half the
  sensor's travel-proportional ``leak``. A hold cannot tell the two apart (both flip with the
  finger's position), so their sum is what the data determine; the parameters apart trade
  off. Computed from the fitted model on an out-back-out drive with the fitted rig, drift
  removed; its standard error by the delta method from the fit's covariance.
- ``f_peak`` (N): half the peak-to-peak swing of the fitted channel over the last two
  strokes of the same drive (the out stroke's extreme less the back stroke's): the static
  peak as the sensor sees it, leak included, as ``f_held`` is the held level; the law's
  ``f_kin + f_static_excess`` alone trades off with the leak. Standard error as for
  ``f_held``.
- ``onset_rate`` (N/s): the steepest rise of the fitted channel over ``ONSET_SAMPLES`` ms in
  the last out stroke of the same drive: the loading as the sensor sees it (stiffness, fast
  relaxation and leak together, at the rig's speed). Standard error as for ``f_held``.
- ``f_static`` (N): the law's static friction level ``f_kin + f_static_excess`` (``f_kin``
  for a law without a peak). Where the force droops over the whole stroke the two trade
  off, their sum does not: its standard error by the delta method, with their covariance.
- ``slip_noise`` (N): the stick-slip intensity, which the smooth law leaves in the residual:
  the RMS of the residual between a ``SLIP_BAND[0]``- and a ``SLIP_BAND[1]``-sample moving
  average (about 40-110 Hz at 1 kHz; a band in samples, so 20-55 Hz at 500 Hz: below a
  50-Hz DAQ low-pass, where a band in hertz would read the filter) within ``SLIP_S`` after
  each command of the fitted motions, less the share of the sensor's white noise in that
  band; the median over the movements, its standard error from their spread. NaN where the
  movements were not fitted sample by sample (``decimate > 1``) or too few were clean.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.fit._numerics import map_chunks
from frictionfit.models import MeasurementModel
from frictionfit.models.measurement import jit_host_loop
from frictionfit.segmentation import moving_average

__all__ = ["DERIVED", "HOLD_S", "LEVELS", "ONSET_SAMPLES", "SLIP_BAND", "SLIP_S",
           "derived_quantities", "slip_noise"]

#: Name -> unit of the derived quantities.
DERIVED = {"f_held": "N", "f_peak": "N", "onset_rate": "N/s", "f_static": "N",
           "slip_noise": "N"}
#: The derived quantities that follow from the parameters (``slip_noise`` is read off the
#: residuals), in the order of their gradients (:func:`derived_quantities`).
LEVELS = ("f_held", "f_peak", "onset_rate", "f_static")
#: Hold (s) between the commands of the drive on which ``f_held`` is read (the protocol's).
HOLD_S = 1.0
#: The span (ms) of the rise in ``onset_rate``: the measured onset rate's filter.
ONSET_SAMPLES = 9
#: Seconds after each command in which ``slip_noise`` is measured.
SLIP_S = 0.25
#: The moving averages (samples) whose difference is the band of ``slip_noise``.
SLIP_BAND = (9, 25)
#: Fewest clean movements for a ``slip_noise``.
MIN_MOVEMENTS = 3
#: Items per call of the levels (one compiled shape whatever the batch: compiling the
#: levels' Jacobian for a new batch size costs far more than running it).
CHUNK = 16


@lru_cache(maxsize=16)
def _levels_fn(model: MeasurementModel):
    """Jitted, vmapped ``(u, direction) -> ((f_held, f_peak, onset_rate, f_static), their
    gradients)`` (signed)."""
    drift = model.param_names.index("drift")
    t = jnp.arange(0.0, 3 * HOLD_S, 1e-3)
    commands, signs = jnp.array([0.0, HOLD_S, 2 * HOLD_S]), jnp.array([1.0, -1.0, 1.0])
    back_start, out_start = round(HOLD_S / 1e-3), round(2 * HOLD_S / 1e-3)

    def levels(u, direction):
        pred = direction * model.predict(u.at[drift].set(0.0), t, commands, signs, direction)
        held = 0.5 * (pred[-1] - pred[out_start - 1])
        peak = 0.5 * (jnp.max(pred[out_start:]) - jnp.min(pred[back_start:out_start]))
        rise = pred[out_start + ONSET_SAMPLES:] - pred[out_start:-ONSET_SAMPLES]
        rate = jnp.max(rise) / (ONSET_SAMPLES * 1e-3)
        v = model.physical(u)
        static = v["f_kin"] + v.get("f_static_excess", 0.0)
        return jnp.stack([held, peak, rate, static])

    def value_and_grad(u, direction):
        grad, value = jax.jacfwd(lambda v: (levels(v, direction),) * 2, has_aux=True)(u)
        return value, grad

    return jit_host_loop(jax.vmap(value_and_grad))


def _band_rms(x: np.ndarray) -> float:
    """RMS of ``x`` between its two moving averages of :data:`SLIP_BAND` (edges dropped)."""
    short, long = SLIP_BAND
    band = (moving_average(x, short) - moving_average(x, long))[long:-long]
    return float(np.sqrt(np.mean(band**2)))


def slip_noise(resid: np.ndarray, t: np.ndarray, weight: np.ndarray, commands: np.ndarray,
               noise: float) -> tuple[float, float]:
    """``slip_noise`` and its standard error (N) from one channel's residuals ``resid`` (N)
    at block times ``t`` (s) with block ``weight``, ``commands`` (s) and the sd ``noise`` (N)
    of one sample (module notes)."""
    short, long = SLIP_BAND
    white = noise**2 * (1.0 / short - 1.0 / long)  # white noise's variance in the band
    per_move = []
    for c in commands:
        window = (t >= c) & (t < c + SLIP_S) & (weight > 0)
        idx = np.flatnonzero(window)
        # sample by sample and without gaps, or the band means nothing
        if idx.size < 3 * long or np.any(weight[idx] != 1.0) or np.any(np.diff(idx) != 1):
            continue
        per_move.append(np.sqrt(max(_band_rms(resid[idx]) ** 2 - white, 0.0)))
    if len(per_move) < MIN_MOVEMENTS:
        return np.nan, np.nan
    return float(np.median(per_move)), float(np.std(per_move, ddof=1) / np.sqrt(len(per_move)))


def derived_quantities(model: MeasurementModel, free: tuple[int, ...], u: np.ndarray,
                       cov: np.ndarray, resid: np.ndarray, items: Sequence,
                       direction: np.ndarray) -> tuple[list[dict[str, tuple[float, float]]],
                                                        list[np.ndarray]]:
    """Per item, name -> ``(value, stderr)`` of :data:`DERIVED` (module notes), and the
    gradients of the :data:`LEVELS` (rows, as reported: of their size) with respect to the
    free unconstrained coordinates (columns), from which their joint covariance follows.

    ``u``: full unconstrained optima; ``cov``: their covariance over ``free``; ``resid``: the
    data residuals ``weight (prediction - y)`` (padded rows); ``items``: the
    :class:`~frictionfit.fit.measurement.MeasurementData` fitted (with the commands the fit used).
    """
    value, grad = map_chunks(_levels_fn(model), (jnp.asarray(u), jnp.asarray(direction)),
                             CHUNK)
    value, grad = np.asarray(value), np.asarray(grad)[:, :, list(free)]
    grad = grad * np.where(value < 0, -1.0, 1.0)[:, :, None]  # f_held, f_peak, onset: sizes
    value = np.abs(value)
    var = np.einsum("nki,nij,nkj->nk", grad, np.nan_to_num(cov), grad)
    var = np.where(np.all(np.isfinite(cov), axis=(1, 2))[:, None], var, np.nan)
    se = np.sqrt(np.maximum(var, 0.0))
    out = []
    for i, d in enumerate(items):
        slip = slip_noise(resid[i, : d.y.size], d.t, d.weight, d.commands, d.noise)
        out.append({name: (float(value[i, q]), float(se[i, q])) for q, name in enumerate(LEVELS)}
                   | {"slip_noise": slip})
    return out, list(grad)
