"""Data-driven starting points and the channel's sign, from the out stroke of each trial."""

from __future__ import annotations

import zlib

import numpy as np

from frictionfit.models import PARAMS, ContactModel

__all__ = ["SATURATED_RUN", "direction_of", "initial_guess", "multi_starts", "saturated_samples",
           "trial_keys"]

#: Consecutive samples exactly at a trial's extreme value that mark it saturated (clipped).
#: Noisy analogue samples never repeat exactly; quantised ones (ADC steps of a few mN) do,
#: in runs far shorter than this, while stuck-transmission faults run much longer and
#: are flagged too.
SATURATED_RUN = 8


def _median(x: np.ndarray, default: float = 0.0) -> float:
    """Median of the finite values of ``x``; ``default`` when there are none."""
    finite = x[np.isfinite(x)]
    return float(np.median(finite)) if finite.size else default


#: Shortest window (s) searched for the out stroke's response: one default movement
#: plus the longest motor delay. When the out phase is shorter (the back command
#: follows within a few samples) the response outlasts it, and a window cut at
#: ``t_back`` would hold only noise: a start far from the data, a wrong sign.
MIN_RESPONSE_S = PARAMS["ramp"].default + PARAMS["delay"].upper


def _out_strokes(t, y, t_out, t_back):
    """Per trial: ``(t_out, t_back, offset, times, y - offset)`` of the out stroke's finite samples.

    The window runs from ``t_out`` to ``t_back``, or to ``t_out + MIN_RESPONSE_S``
    when the out phase is shorter.
    """
    t_out = np.broadcast_to(np.asarray(t_out, dtype=np.float64), (y.shape[0],))
    t_back = np.broadcast_to(np.asarray(t_back, dtype=np.float64), (y.shape[0],))
    for yi, to, tb in zip(y, t_out, t_back, strict=True):
        offset = _median(yi[t < to], default=_median(yi))
        window = (t >= to) & (t < max(tb, to + MIN_RESPONSE_S))
        dev = yi[window] - offset
        finite = np.isfinite(dev)
        yield to, tb, offset, t[window][finite], dev[finite]


def initial_guess(model: ContactModel, t, y, t_out, t_back, direction) -> np.ndarray:
    """Data-driven starting points (unconstrained, ``(n_trials, n_params)``).

    Offset from the samples before the out command; motor delay from the force
    onset; friction from the peak of the out stroke; stiffness from the peak force
    over the (raised-cosine) displacement reached at the peak (the out movement
    from the onset, minus the back movement when the out phase is shorter than a
    movement); relaxation from the drop between the peak and the end of the out phase.
    """
    y = np.asarray(y, dtype=np.float64)
    rows = []
    strokes = _out_strokes(t, y, t_out, t_back)
    for (to, tb, offset, tw, dev), d in zip(strokes, direction, strict=True):
        out = d * dev
        peak = max(float(out.max()), 1e-3) if out.size else 1e-3
        held = out[tw < tb]
        end = float(np.median(held[-50:])) if held.size >= 50 else 0.5 * peak
        guess = dict(offset=offset, f_kin=0.8 * peak, f_static_excess=0.2 * peak,
                     relax_frac=float(np.clip(1 - end / peak, 0.05, 0.9)))
        if out.size:
            t_peak = tw[np.argmax(out)]
            t_onset = tw[np.argmax(out > 0.1 * peak)]
            guess["delay"] = float(np.clip(t_onset - to, 0.002, 0.25))
            ramp = PARAMS["ramp"].default
            phase = (t_peak - t_onset) / ramp
            reached = (0.5 - 0.5 * np.cos(np.pi * np.clip(phase, 0.02, 1.0))
                       - (0.5 - 0.5 * np.cos(np.pi * np.clip(phase - (tb - to) / ramp, 0.0, 1.0))))
            reached = max(reached, 1e-4)
            guess["k"] = float(np.clip(peak / (reached * model.stroke_mm), 1e-2, 5e3))
        rows.append([
            PARAMS[n].to_unconstrained(guess.get(n, PARAMS[n].default)) for n in model.param_names
        ])
    return np.asarray(rows, dtype=np.float64)


def trial_keys(y) -> np.ndarray:
    """One 32-bit key per trial from its own samples (CRC-32 of the float64 bytes).

    Seeds each trial's multi-start jitter from what the trial *is*, not from where
    it sits: the same trial gets the same starts alone, in any batch, at any
    position, and in any chunk of a distributed fit; identical trials get
    identical starts (so bit-identical results).
    """
    y = np.ascontiguousarray(np.atleast_2d(np.asarray(y, dtype=np.float64)))
    return np.array([zlib.crc32(row.tobytes()) for row in y], dtype=np.int64)


def multi_starts(model: ContactModel, u0: np.ndarray, n_starts: int, seed: int,
                 spread: float = 1.0, keys=None) -> np.ndarray:
    """``(n_starts, n_trials, n_params)`` starting points: ``u0`` first, then seeded jitter.

    The jitter is Gaussian in the unconstrained coordinates (sd ``spread``) of the
    bounded parameters, so a log-scaled one moves by a factor of a few; offsets
    (data-driven and well determined) are not jittered. Each trial draws from its
    own generator, seeded by ``(seed, keys[i])`` (``keys``: e.g. :func:`trial_keys`;
    the trial's index when omitted), so its starts do not depend on the other
    trials of the batch. Deterministic given ``seed`` and ``keys``.
    """
    n_trials, n_params = u0.shape
    keys = np.arange(n_trials) if keys is None else np.asarray(keys)
    bounded = np.array([p.transform != "identity" for p in model.params], dtype=np.float64)
    jitter = np.zeros((max(n_starts - 1, 0), n_trials, n_params))
    if n_starts > 1:
        for i, key in enumerate(keys):
            rng = np.random.default_rng([int(seed), int(key)])
            jitter[:, i] = rng.normal(0.0, spread, (n_starts - 1, n_params))
    return np.concatenate([u0[None], u0[None] + jitter * bounded])


def saturated_samples(y, min_run: int = SATURATED_RUN) -> np.ndarray:
    """Boolean ``(n_trials, n_samples)``: samples in a run of ``min_run`` or more at the extreme.

    A run is consecutive finite samples exactly equal to the trial's largest (or
    smallest) finite value, which is what a clipping amplifier or ADC leaves. A
    constant (dead) channel is not marked: it has no extreme to be clipped at, and
    its fit is flagged as not identifiable instead.
    """
    y = np.atleast_2d(np.asarray(y, dtype=np.float64))
    out = np.zeros(y.shape, dtype=bool)
    for i, row in enumerate(y):
        finite = np.isfinite(row)
        if not finite.any():
            continue
        lo, hi = np.min(row[finite]), np.max(row[finite])
        if lo == hi:
            continue
        for ext in (lo, hi):
            edges = np.diff(np.concatenate([[0], (row == ext).astype(np.int8), [0]]))
            for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
                if b - a >= min_run:
                    out[i, a:b] = True
    return out


def direction_of(t, y, t_out, t_back) -> np.ndarray:
    """+1/-1 per trial: the sign of the largest deviation during the out phase."""
    return np.asarray([1.0 if dev.size == 0 or dev.max() >= -dev.min() else -1.0
                       for *_, dev in _out_strokes(t, y, t_out, t_back)])
