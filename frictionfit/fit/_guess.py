"""Data-driven starting points and the channel's sign, from the out stroke of each trial."""

from __future__ import annotations

import numpy as np

from frictionfit.models import PARAMS, ContactModel

__all__ = ["direction_of", "initial_guess", "multi_starts"]


def _median(x: np.ndarray, default: float = 0.0) -> float:
    """Median of the finite values of ``x``; ``default`` when there are none."""
    finite = x[np.isfinite(x)]
    return float(np.median(finite)) if finite.size else default


def _out_strokes(t, y, t_out, t_back):
    """Per trial: baseline offset (N) and the finite out-stroke samples ``(times, y - offset)``."""
    t_out = np.broadcast_to(np.asarray(t_out, dtype=np.float64), (y.shape[0],))
    t_back = np.broadcast_to(np.asarray(t_back, dtype=np.float64), (y.shape[0],))
    for yi, to, tb in zip(y, t_out, t_back, strict=True):
        offset = _median(yi[t < to], default=_median(yi))
        window = (t >= to) & (t < tb)
        dev = yi[window] - offset
        finite = np.isfinite(dev)
        yield to, offset, t[window][finite], dev[finite]


def initial_guess(model: ContactModel, t, y, t_out, t_back, direction) -> np.ndarray:
    """Data-driven starting points (unconstrained, ``(n_trials, n_params)``).

    Offset from the samples before the out command; motor delay from the force
    onset; friction from the peak of the out stroke; stiffness from the peak force
    over the (raised-cosine) displacement reached between onset and peak;
    relaxation from the drop between the peak and the end of the out phase.
    """
    y = np.asarray(y, dtype=np.float64)
    rows = []
    strokes = _out_strokes(t, y, t_out, t_back)
    for (to, offset, tw, dev), d in zip(strokes, direction, strict=True):
        out = d * dev
        peak = max(float(out.max()), 1e-3) if out.size else 1e-3
        end = float(np.median(out[-50:])) if out.size >= 50 else 0.5 * peak
        guess = dict(offset=offset, f_kin=0.8 * peak, f_static_excess=0.2 * peak,
                     relax_frac=float(np.clip(1 - end / peak, 0.05, 0.9)))
        if out.size:
            t_peak = tw[np.argmax(out)]
            t_onset = tw[np.argmax(out > 0.1 * peak)]
            guess["delay"] = float(np.clip(t_onset - to, 0.002, 0.25))
            ramp = PARAMS["ramp"].default
            reached = 0.5 - 0.5 * np.cos(np.pi * np.clip((t_peak - t_onset) / ramp, 0.02, 1.0))
            guess["k"] = float(np.clip(peak / (reached * model.stroke_mm), 1e-2, 5e3))
        rows.append([
            PARAMS[n].to_unconstrained(guess.get(n, PARAMS[n].default)) for n in model.param_names
        ])
    return np.asarray(rows, dtype=np.float64)


def multi_starts(model: ContactModel, u0: np.ndarray, n_starts: int, seed: int,
                 spread: float = 1.0) -> np.ndarray:
    """``(n_starts, n_trials, n_params)`` starting points: ``u0`` first, then seeded jitter.

    The jitter is Gaussian in the unconstrained coordinates (sd ``spread``) of the
    bounded parameters, so a log-scaled one moves by a factor of a few; offsets
    (data-driven and well determined) are not jittered. Deterministic given ``seed``.
    """
    rng = np.random.default_rng(seed)
    bounded = np.array([p.transform != "identity" for p in model.params], dtype=np.float64)
    jitter = rng.normal(0.0, spread, (n_starts - 1, *u0.shape)) * bounded
    return np.concatenate([u0[None], u0[None] + jitter])


def direction_of(t, y, t_out, t_back) -> np.ndarray:
    """+1/-1 per trial: the sign of the largest deviation during the out phase."""
    return np.asarray([1.0 if dev.size == 0 or dev.max() >= -dev.min() else -1.0
                       for _, _, _, dev in _out_strokes(t, y, t_out, t_back)])
