"""Physical features of a FabricSlide slide: the contact model's breakaway and the stick-slip.

**Texture, not mounting.** Every feature is computed from the taxels with each
taxel's own mean (or linear trend, in the steady part) removed, and amplitudes are relative to a
taxel's own dynamic range, so a constant offset added to any taxel (a new grasp, a
new bias reading) changes nothing, and the proximity words are never read.

**Observable.** The finger's taxel layout is not documented, so no shear proxy can
be built from geometry; the contact model is fitted to the first principal
component (PC1) of the centred taxels, i.e. the load change all taxels share
(sign: loadings sum positive), divided by its own 5-95 % range (unitless, "r").

**Contact model over the whole slide.** The drive is the known travel: a
quarter-sine velocity ramp of duration ``ramp_s`` (covering ``2 |v| ramp_s / pi``
mm) then constant ``|v|``. The observable, block-averaged to ``N_FIT`` points (the
model describes the load-up, the breakaway and the slow relaxation, not each
stick-slip cycle), is fitted by the ``relaxation`` member of the family (play
operator with slip weakening plus a Maxwell branch) with ``drive="given"``:
loading stiffness ``k`` (r/mm), static/kinetic ratio ``1 + f_static_excess /
f_kin``, slip-weakening length (mm) and relaxation time ``tau`` (s), with the
relative standard error of ``k``. Slides of one speed share one batched fit.
The stick-slip itself is described by cycle statistics of the steady part.

**Steady part (ramps excluded).** Stick-slip period (s and mm of travel) at the
largest peak of the PC1 spectrum outside the grip-loop line (2.0-2.6 Hz), its
amplitude (sd of PC1 / its 5-95 % range), the slip asymmetry (skewness of the
sample-to-sample change: slow loading, fast slip gives a negative value), slip
events per 100 mm, each taxel's amplitude relative to the taxels' geometric mean
(16), and each taxel's spectral shape: log mean power in 8 log-spaced bands from
0.25 to 17.5 Hz (a band without a Welch bin takes the nearest bin) minus the log of
its total power (8 x 16). The grip-loop line (2.0-2.6 Hz; mechanical, its
frequency does not follow the speed and its strength differs between recording
runs, so it can tell runs apart rather than fabrics) is left out of the bands and of
the total: leave-one-pressure-out 0.929 with it, 0.960 without (one of four
variants tried on the same data, so slightly optimistic).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import signal, stats

from frictionfit.datasets.fabricslide import TAXELS
from frictionfit.errors import RecordingError, Status
from frictionfit.features._base import RecordingFeatures
from frictionfit.models.family import PARAMS
from frictionfit.recording import Recording

__all__ = ["SlidingPhysicalFeatures", "fit_breakaway", "slide_drive", "steady_features"]

#: Fraction of a slide taken by each ramp when the metadata lacks ``ramp_s``.
RAMP_FRACTION = 0.079
#: Band (Hz) of the speed-independent grip-loop line, excluded from the stick-slip peak.
GRIP_LOOP_HZ = (2.0, 2.6)
#: Bands (Hz) of the per-taxel spectral shape: log-spaced, either side of the grip-loop line.
BANDS_HZ = ((0.25, 0.42), (0.42, 0.72), (0.72, 1.23), (1.23, 2.0),
            (2.6, 3.55), (3.55, 6.04), (6.04, 10.3), (10.3, 17.5))
CONTACT_MODEL = "relaxation"
#: Points of the whole-slide observable the contact model is fitted to.
N_FIT = 128
#: Decimals kept of the range-normalised observable fed to the contact-model fit.
OBSERVABLE_DECIMALS = 9
_CYCLE_NAMES = ["stick_slip_period [s]", "stick_slip_period [mm]", "stick_slip_amplitude [1]",
                "slip_asymmetry [1]", "slip_events [1/100 mm]"]
_FIT_NAMES = ["loading_stiffness [1/mm]", "static_kinetic_ratio [1]", "slip_length [mm]",
              "relaxation_time [s]", "relaxation_fraction [1]", "log_stiffness_stderr [1]",
              "breakaway_sign [1]", "contact_fit_r2 [1]", "contact_fit_ok [1]"]


def slide_drive(t: np.ndarray, speed: float, ramp_s: float) -> np.ndarray:
    """Travel (mm) at times ``t`` (s): quarter-sine velocity ramp over ``ramp_s``, then |speed|."""
    v = abs(speed)
    phase = 0.5 * np.pi * np.clip(t, 0.0, ramp_s) / ramp_s
    in_ramp = 2.0 * v * ramp_s / np.pi * (1.0 - np.cos(phase))
    return in_ramp + v * np.clip(t - ramp_s, 0.0, None)


def _slide_info(rec: Recording) -> tuple[float, float]:
    speed = rec.metadata.get("speed")
    if speed is None or not np.isfinite(float(speed)) or float(speed) == 0:
        raise RecordingError("metadata lacks a non-zero sliding 'speed' (mm/s)", path=rec.name)
    ramp_s = float(rec.metadata.get("ramp_s", RAMP_FRACTION * rec.duration_s))
    return float(speed), ramp_s


def _taxels(rec: Recording) -> np.ndarray:
    return np.column_stack([rec.channel(c) for c in TAXELS])


def _pc1(x: np.ndarray) -> np.ndarray:
    """First principal component of the centred columns, sign fixed, over its 5-95 % range."""
    xc = x - x.mean(axis=0)
    u, s, vt = np.linalg.svd(xc, full_matrices=False)
    pc = u[:, 0] * s[0] * (1.0 if vt[0].sum() >= 0 else -1.0)
    span = np.subtract(*np.percentile(pc, [95, 5]))
    return pc / (span if span > 0 else 1.0)


def steady_features(rec: Recording) -> np.ndarray:
    """Stick-slip cycle statistics and per-taxel amplitude/spectral shape of the steady part."""
    speed, ramp_s = _slide_info(rec)
    keep = (rec.t >= ramp_s) & (rec.t <= rec.t[-1] - ramp_s)
    if keep.sum() < 16:
        raise RecordingError(f"only {int(keep.sum())} samples at constant speed", path=rec.name)
    x = signal.detrend(_taxels(rec)[keep], axis=0)
    fs = rec.sample_rate_hz
    pc = _pc1(x)
    f, p = signal.welch(pc, fs, nperseg=min(256, pc.size))
    allowed = (f > 0) & ((f < GRIP_LOOP_HZ[0]) | (f > GRIP_LOOP_HZ[1]))
    f_peak = f[allowed][np.argmax(p[allowed])]
    d = np.diff(pc)
    slips = np.flatnonzero(np.diff((d < -2.0 * d.std()).astype(int)) == 1).size
    travel_mm = abs(speed) * pc.size / fs
    cycle = [1.0 / f_peak, abs(speed) / f_peak, pc.std(), stats.skew(d), 100.0 * slips / travel_mm]
    sd = np.maximum(x.std(axis=0), 1e-12)
    amp = np.log(sd) - np.log(sd).mean()
    f, p = signal.welch(x, fs, nperseg=min(64, x.shape[0]), axis=0)
    texture = (f < GRIP_LOOP_HZ[0]) | (f > GRIP_LOOP_HZ[1])
    total = np.log(p[texture].sum(axis=0) + 1e-300)
    bands = []
    for lo, hi in BANDS_HZ:
        inside = (f >= lo) & (f < hi) & texture
        power = p[inside].mean(axis=0) if inside.any() else p[np.argmin(abs(f - np.sqrt(lo * hi)))]
        bands.append(np.log(power + 1e-300) - total)
    return np.concatenate([cycle, amp, np.ravel(bands)])


def _fit_windows(recordings: Sequence[Recording]):
    """Per recording: ``N_FIT`` uniform times over the slide, the PC1 observable, the travel.

    The observable is block-averaged to the coarser grid (a moving mean as wide as
    one grid step) before it is interpolated, so no stick-slip cycle aliases into it.
    """
    for rec in recordings:
        speed, ramp_s = _slide_info(rec)
        t = np.linspace(0.0, rec.t[-1], N_FIT)
        width = max(1, int(round(rec.n_samples / N_FIT)))
        pc = _pc1(_taxels(rec))
        smooth = np.convolve(np.pad(pc, (width // 2, width - 1 - width // 2), mode="edge"),
                             np.full(width, 1.0 / width), mode="valid")
        # Rounded far below one count so that offset-shifted taxels (equal up to float
        # rounding after centring) give bitwise-equal inputs, hence identical fits.
        y = np.round(np.interp(t, rec.t, smooth), OBSERVABLE_DECIMALS)
        yield round(abs(speed), 6), t, y, slide_drive(t, speed, ramp_s)


def _start_guess(y: np.ndarray, x: np.ndarray, duration_s: float) -> tuple[list[float], float]:
    """Unconstrained starting point and load-up sign (+1/-1) from a slide's observable.

    The sign is that of the mean change over the first quarter of the slide; the
    static peak is the largest signed change there, the kinetic level the median
    of the last quarter, the stiffness the peak over the travel reached at it.
    """
    dev = y - y[:2].mean()
    quarter = max(2, dev.size // 4)
    sign = 1.0 if dev[:quarter].mean() >= 0 else -1.0
    dev = sign * dev
    i = int(np.argmax(dev[:quarter]))
    peak = max(float(dev[i]), 1e-3)
    plateau = float(np.clip(np.median(dev[-quarter:]), 0.05 * peak, peak))
    guess = {"offset": y[:2].mean(), "k": float(np.clip(peak / max(x[i], 0.5), 1e-3, 1e3)),
             "f_kin": plateau, "f_static_excess": max(peak - plateau, 1e-3),
             "slip_length": 2.0, "relax_frac": 0.3, "tau": 0.2 * duration_s}
    names = ("offset", "k", "f_kin", "f_static_excess", "slip_length", "relax_frac", "tau")
    return [PARAMS[n].to_unconstrained(guess[n]) for n in names], sign


def fit_breakaway(recordings: Sequence[Recording], max_steps: int = 200) -> np.ndarray:
    """Fit the contact model to each whole slide; rows of the ``_FIT_NAMES`` features.

    Recordings are batched by speed (one :func:`~frictionfit.fit.fit_trials`
    call per speed). A fit that fails keeps its values and gets ``contact_fit_ok = 0``;
    a non-finite value is replaced by the parameter's default (and flagged the same way).
    """
    from frictionfit.fit import fit_trials

    windows = list(_fit_windows(recordings))
    out = np.empty((len(windows), len(_FIT_NAMES)))
    for speed in sorted({w[0] for w in windows}):
        idx = [i for i, w in enumerate(windows) if w[0] == speed]
        t = windows[idx[0]][1]
        y = np.vstack([windows[i][2] for i in idx])
        x = np.vstack([windows[i][3] for i in idx])
        guesses = [_start_guess(yi, xi, t[-1]) for yi, xi in zip(y, x, strict=True)]
        u0 = np.asarray([g[0] for g in guesses])
        sign = np.asarray([g[1] for g in guesses])
        res = fit_trials(y, t, x, model=CONTACT_MODEL, drive="given", u0=u0, direction=sign,
                         max_steps=max_steps)
        for row, i in enumerate(idx):
            v, se = res.params(row), res.stderrs(row)
            log_k_se = se["k"] / v["k"] if np.isfinite(se["k"]) and v["k"] > 0 else 10.0
            vals = [v["k"], 1.0 + v["f_static_excess"] / v["f_kin"], v["slip_length"], v["tau"],
                    v["relax_frac"], min(log_k_se, 10.0), sign[row], res.r2[row],
                    float(res.status[row] == Status.CONVERGED)]
            vals = np.asarray(vals, dtype=np.float64)
            if not np.all(np.isfinite(vals)):
                vals = np.where(np.isfinite(vals), vals, 1.0)
                vals[-1] = 0.0
            out[i] = vals
    out[:, :4] = np.log(out[:, :4])
    return out


class SlidingPhysicalFeatures(RecordingFeatures):
    """Contact-model breakaway fit and stick-slip statistics of FabricSlide slides.

    Invariant to a constant offset on any taxel and blind to the proximity words
    (see the module docstring for the definitions and units). Stiffness, ratio,
    slip length and relaxation time are given as natural logs.

    Parameters
    ----------
    max_steps : int, default 200
        Solver steps per contact-model fit.
    cache : bool, default True
        Cache rows per recording content (see :mod:`frictionfit.features._base`).
    """

    _version = 1

    def __init__(self, max_steps: int = 200, cache: bool = True):
        self.max_steps = max_steps
        self.cache = cache

    def _extract(self, recordings: Sequence[Recording]) -> np.ndarray:
        steady = np.vstack([steady_features(r) for r in recordings])
        return np.hstack([fit_breakaway(recordings, self.max_steps), steady])

    def _names(self) -> list[str]:
        fit = [f"sliding:log_{n}" if i < 4 else f"sliding:{n}" for i, n in enumerate(_FIT_NAMES)]
        amp = [f"sliding:amplitude_share:{c} [log]" for c in TAXELS]
        bands = [f"sliding:band_{lo:.3g}-{hi:.3g}Hz:{c} [log share]"
                 for lo, hi in BANDS_HZ for c in TAXELS]
        return fit + [f"sliding:{n}" for n in _CYCLE_NAMES] + amp + bands
