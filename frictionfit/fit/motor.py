"""Each movement of the motor as it reported it: onset, duration and acceleration share.

``frictionfit rub`` can read the actuator's present position between its commands
(:meth:`~frictionfit.recording.Recording.motor_positions`). :func:`motor_timing` fits those
reads by least squares with the measurement model's own drive: every movement the
trapezoid velocity profile (:func:`~frictionfit.models.measurement.trapezoid`) with its own
onset and duration, one acceleration share per recording, from the level before it to the
level after. The whole fits then take each movement's timing from the motor instead of
finding it in the force.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from frictionfit.errors import RecordingError
from frictionfit.fit.solver import DATA_FTOL, DATA_RTOL, BatchedLevenbergMarquardt
from frictionfit.models.measurement import trapezoid
from frictionfit.recording import Recording, kept_per_recording

__all__ = ["MotorTiming", "motor_timing"]

#: Fewest reads inside a movement (between its onset and its stop) for its own timing.
MIN_READS = 2
#: The reads are padded (weight 0) to a multiple of this: one compiled shape per 20 s of
#: reads at 50 Hz.
READS_CHUNK = 1024
#: Largest RMS misfit of the reads, as a share of the movement's step: beyond it the reads
#: do not show trapezoid-like movements (a stalled or slipping drive) and are not used.
MAX_MISFIT = 0.05


@dataclass(frozen=True)
class MotorTiming:
    """The motor's movements: ``onset`` and ``duration`` (s) per ``move`` command (NaN where
    too few reads fell inside the movement), the acceleration share ``accel`` of the
    recording, and the RMS misfit of the reads (counts) with their number."""

    onset: np.ndarray
    duration: np.ndarray
    accel: float
    rms_counts: float
    n_reads: int

    @property
    def seen(self) -> np.ndarray:
        """The movements whose timing the reads determine."""
        return np.isfinite(self.onset)


def _accel(z):
    """The acceleration share (0 to 0.5) of the unconstrained ``z[2]``."""
    return 0.5 * jax.nn.sigmoid(z[2])


@lru_cache(maxsize=4)
def _solve(n_moves: int):
    """Jitted ``(z0, t, x, weight, signs) -> (z, converged, residuals)``: the least-squares
    fit of ``z = (level, step, logit of 2 accel, onsets, log durations)`` to the reads."""

    def residual(z, args):
        t, x, weight, signs = args
        onset, duration = z[3:3 + n_moves], jnp.exp(z[3 + n_moves:])
        share = trapezoid((t[:, None] - onset[None]) / duration[None], _accel(z))[0]
        return weight * (z[0] + z[1] * share @ signs - x)

    def solve(z0, t, x, weight, signs):
        args = (t, x, weight, signs)
        solver = BatchedLevenbergMarquardt(rtol=DATA_RTOL, ftol=DATA_FTOL)
        sol = optx.least_squares(residual, solver, z0, args=args, max_steps=200, throw=False)
        return sol.value, sol.result == optx.RESULTS.successful, residual(sol.value, args)

    return jax.jit(solve)


def _crossing(t: np.ndarray, x: np.ndarray, level: float) -> float:
    """First time (s) the reads ``x`` pass ``level`` (linear between reads; NaN if never)."""
    above = (x - level) * np.sign(x[-1] - x[0]) >= 0
    k = int(np.argmax(above))
    if not above[k] or k == 0:
        return np.nan
    xs, ts = x[k - 1:k + 1], t[k - 1:k + 1]
    order = np.argsort(xs)
    return float(np.interp(level, xs[order], ts[order]))


@kept_per_recording
def motor_timing(rec: Recording, commands: np.ndarray, signs: np.ndarray) -> MotorTiming | None:
    """The motor's movements after the ``move`` ``commands`` (s; ``signs`` +1 out, -1 back)
    from ``rec``'s position reads; None when ``rec`` holds none, too few to fit, or reads
    that no trapezoid-like movements describe (misfit above :data:`MAX_MISFIT`); a
    malformed reads block is named in a warning and treated as none (the forces stay
    usable). A movement is timed only where at least :data:`MIN_READS` reads fall inside it
    and it lies between its command and the next one. Kept per recording: each of its
    channels asks for the same timing."""
    try:
        reads = rec.motor_positions()
    except RecordingError as exc:
        warnings.warn(f"{exc}; each movement's timing is found in the force instead",
                      stacklevel=4)
        return None
    if reads is None:
        return None
    t, x = (np.asarray(a, dtype=np.float64) for a in reads)
    ok = np.isfinite(t) & np.isfinite(x)
    t, x = t[ok], x[ok]
    if t.size < 4 * commands.size:
        return None
    ends = np.r_[commands[1:], np.inf]
    before = x[t < commands[0]]
    level = float(np.median(before)) if before.size else float(x[0])
    after = x[(t >= commands[0] + 0.5 * (ends[0] - commands[0])) & (t < ends[0])]
    if after.size == 0 or np.median(after) == level:
        return None
    step = float(np.median(after)) - level
    onset0, duration0 = [], []
    for c, e, s in zip(commands, ends, signs, strict=True):  # each movement's middle
        inside = (t >= c) & (t < e)
        start = level + step * (s < 0)
        mid = _crossing(t[inside], x[inside], start + 0.5 * step * s)
        onset0.append(mid - 0.06 if np.isfinite(mid) else c + 0.02)
        duration0.append(0.12)
    z0 = np.r_[level, step, 0.0, onset0, np.log(duration0)]
    pad = np.zeros(-t.size % READS_CHUNK)
    z, converged, resid = _solve(commands.size)(
        jnp.asarray(z0), jnp.asarray(np.r_[t, pad]), jnp.asarray(np.r_[x, pad]),
        jnp.asarray(np.r_[np.ones(t.size), pad]), jnp.asarray(signs, dtype=np.float64))
    z = np.asarray(z)
    if not bool(converged) or not np.all(np.isfinite(z)):
        return None
    rms = float(np.sqrt(np.mean(np.asarray(resid)[: t.size] ** 2)))
    if rms > MAX_MISFIT * abs(z[1]):
        return None
    m = commands.size
    onset, duration = z[3:3 + m], np.exp(z[3 + m:])
    inside = ((t[:, None] > onset[None]) & (t[:, None] < (onset + duration)[None])).sum(axis=0)
    seen = (inside >= MIN_READS) & (onset >= commands) & (onset + duration <= ends)
    return MotorTiming(np.where(seen, onset, np.nan), np.where(seen, duration, np.nan),
                       float(_accel(z)), rms, int(t.size))
