"""Physical features of a FabricSlide slide: texture beyond the grip, scaled by the grip.

**The grip is observed, not a class.** The grip loop regulates the taxels' trimmed
mean, so the taxels measure the normal load (:mod:`frictionfit.features.grip`): its
level (the grip load, counts) and its variation in time as the loop re-commands the
gripper (the mean over taxels), which every taxel follows with its own gain. The
texture features are computed from the taxels without that response, and each is
brought to a reference load by a power law whose exponent is fitted within the fabrics
across the training grips (:class:`~frictionfit.features.grip.GripLaw`), so a new
grip is read through the law. The default ``grip="stroke"`` measures the load by
the stroke shift (:func:`~frictionfit.features.grip.stroke_shift`: the load the stroke
shifts between the taxels, from the start ramp to the end ramp), ``grip="breakaway"``
by the breakaway shift (:func:`~frictionfit.features.grip.breakaway_shift`: the same
from the start to the steady part); a constant offset on a taxel moves neither.
``grip="scaled"`` measures it by the grip load (the taxels' level), which the offset
does move; ``grip="none"`` leaves the features as observed.

**Texture, not mounting.** Each taxel's own mean (or linear trend, in the steady part)
is removed and amplitudes are relative to a taxel's own dynamic range, so a constant
offset added to any taxel changes no texture value and no stroke or breakaway shift (with
``grip="scaled"``, the grip load moves and the scaled values with it), and the
proximity words are never read.

**Slide model (``contact=True`` exposes it; always computed).** The observable is the
first principal component (PC1) of the centred taxels (sign: loadings sum positive)
over its own 5-95 % range ("r"), block-averaged to ``N_FIT`` points over the whole
slide. It is modelled as its least-squares response to the observed load's variation
plus the ``relaxation`` member of the family (play operator with slip weakening plus a
Maxwell branch) driven by the known travel (``drive="given"``; quarter-sine velocity
ramp of ``ramp_s``, then constant ``|v|``), fitted to what the load leaves: loading
stiffness ``k`` (r/mm), static/kinetic ratio ``1 + f_static_excess / f_kin``,
slip-weakening length (mm), relaxation time ``tau`` (s), the relative standard error
of ``k``, the R^2 of the whole slide model (``contact_fit_r2``) and of the contact law
on what the load leaves (``contact_law_r2``), and the observable's range in counts
(``log_slide_span``: ``k`` times it is a stiffness in counts/mm). Slides of one speed
share one batched fit.

**Steady part (ramps excluded), load-free taxels.** Stick-slip period (s and mm of
travel) at the largest peak of the PC1 spectrum outside the grip-loop line
(2.0-2.6 Hz), its amplitude (sd of PC1 / its 5-95 % range), the slip asymmetry
(skewness of the sample-to-sample change; the load-free loadings sum to zero, so
PC1's sign is set to make it negative: the fast phase is the slip), slip events
(fast drops) per 100 mm, the texture amplitude (mean log sd of the taxels,
counts), each taxel's amplitude relative to the taxels' geometric mean (16), and each
taxel's spectral shape: log mean power in 8 log-spaced bands from 0.25 to 17.5 Hz (a
band without a Welch bin takes the nearest bin) minus the log of its total power
(8 x 16). The grip-loop line (mechanical: its frequency does not follow the speed and
its strength differs between recording runs) is left out of the bands and the total.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import signal, stats
from sklearn.utils.validation import check_is_fitted

from frictionfit.datasets.fabricslide import TAXELS
from frictionfit.errors import RecordingError, Status
from frictionfit.features._base import RecordingFeatures
from frictionfit.features.grip import (
    RAMP_FRACTION,
    GripLaw,
    breakaway_shift,
    grip_load,
    load_signal,
    steady_part,
    stroke_shift,
    without_load,
)
from frictionfit.models.family import PARAMS
from frictionfit.recording import Recording

__all__ = ["SlidingPhysicalFeatures", "fit_breakaway", "slide_drive", "steady_features"]

#: Band (Hz) of the speed-independent grip-loop line, excluded from the stick-slip peak.
GRIP_LOOP_HZ = (2.0, 2.6)
#: Bands (Hz) of the per-taxel spectral shape: log-spaced, either side of the grip-loop line.
BANDS_HZ = ((0.25, 0.42), (0.42, 0.72), (0.72, 1.23), (1.23, 2.0),
            (2.6, 3.55), (3.55, 6.04), (6.04, 10.3), (10.3, 17.5))
#: Measures of the load (counts) a feature's grip law is fitted against, by ``grip`` name.
GRIP_MEASURES = {"stroke": stroke_shift, "breakaway": breakaway_shift, "scaled": grip_load,
                 "none": None}
CONTACT_MODEL = "relaxation"
#: Points of the whole-slide observable the contact model is fitted to.
N_FIT = 128
#: Decimals kept of the range-normalised observable fed to the contact-model fit.
OBSERVABLE_DECIMALS = 9
_CYCLE_NAMES = ["stick_slip_period [s]", "stick_slip_period [mm]", "stick_slip_amplitude [1]",
                "slip_asymmetry [1]", "slip_events [1/100 mm]", "log_texture_amplitude [counts]"]
_FIT_NAMES = ["loading_stiffness [1/mm]", "static_kinetic_ratio [1]", "slip_length [mm]",
              "relaxation_time [s]", "relaxation_fraction [1]", "log_stiffness_stderr [1]",
              "breakaway_sign [1]", "contact_fit_r2 [1]", "contact_fit_ok [1]",
              "log_slide_span [counts]", "contact_law_r2 [1]"]


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


def _pc1(x: np.ndarray, span_out: list | None = None) -> np.ndarray:
    """First principal component of the centred columns, sign fixed, over its 5-95 % range.

    The range (in the columns' units) is appended to ``span_out`` when given.
    """
    xc = x - x.mean(axis=0)
    u, s, vt = np.linalg.svd(xc, full_matrices=False)
    pc = u[:, 0] * s[0] * (1.0 if vt[0].sum() >= 0 else -1.0)
    span = np.subtract(*np.percentile(pc, [95, 5]))
    span = span if span > 0 else 1.0
    if span_out is not None:
        span_out.append(float(span))
    return pc / span


def steady_features(rec: Recording) -> np.ndarray:
    """Stick-slip cycle statistics and per-taxel amplitude/spectral shape of the steady part.

    Computed from the taxels without their response to the load's variation
    (:func:`~frictionfit.features.grip.without_load`), so the grip loop's re-commands
    are not taken for texture.
    """
    speed, _ = _slide_info(rec)
    keep = steady_part(rec)
    if keep.sum() < 16:
        raise RecordingError(f"only {int(keep.sum())} samples at constant speed", path=rec.name)
    x = without_load(signal.detrend(_taxels(rec)[keep], axis=0))
    fs = rec.sample_rate_hz
    pc = _pc1(x)
    if stats.skew(np.diff(pc)) > 0:  # load-free loadings sum to zero: the slip sets the sign
        pc = -pc
    f, p = signal.welch(pc, fs, nperseg=min(256, pc.size))
    allowed = (f > 0) & ((f < GRIP_LOOP_HZ[0]) | (f > GRIP_LOOP_HZ[1]))
    f_peak = f[allowed][np.argmax(p[allowed])]
    d = np.diff(pc)
    slips = np.flatnonzero(np.diff((d < -2.0 * d.std()).astype(int)) == 1).size
    travel_mm = abs(speed) * pc.size / fs
    sd = np.maximum(x.std(axis=0), 1e-12)
    cycle = [1.0 / f_peak, abs(speed) / f_peak, pc.std(), stats.skew(d),
             100.0 * slips / travel_mm, np.log(sd).mean()]
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


def _block_mean(y: np.ndarray, rec: Recording, t: np.ndarray) -> np.ndarray:
    """``y`` smoothed by a moving mean one grid step wide, at the grid times ``t``."""
    width = max(1, int(round(rec.n_samples / t.size)))
    smooth = np.convolve(np.pad(y, (width // 2, width - 1 - width // 2), mode="edge"),
                         np.full(width, 1.0 / width), mode="valid")
    # Rounded far below one count so that offset-shifted taxels (equal up to float
    # rounding after centring) give bitwise-equal inputs, hence identical fits.
    return np.round(np.interp(t, rec.t, smooth), OBSERVABLE_DECIMALS)


def _fit_windows(recordings: Sequence[Recording]):
    """Per recording: speed, ``N_FIT`` uniform times over the slide, the PC1 observable, the
    load's variation on the observable's scale, the travel and the observable's range (counts).

    Both signals are block-averaged to the coarser grid (a moving mean as wide as
    one grid step) before they are interpolated, so no stick-slip cycle aliases into them.
    """
    for rec in recordings:
        speed, ramp_s = _slide_info(rec)
        t = np.linspace(0.0, rec.t[-1], N_FIT)
        taxels, span = _taxels(rec), []
        y = _block_mean(_pc1(taxels, span), rec, t)
        n = _block_mean(load_signal(taxels) / span[0], rec, t)
        yield round(abs(speed), 6), t, y, n, slide_drive(t, speed, ramp_s), span[0]


def _load_term(y: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The least-squares response of ``y`` to the centred load variation ``n``."""
    nc = n - n.mean()
    nn = float(nc @ nc)
    return (float(nc @ (y - y.mean())) / nn if nn > 0 else 0.0) * nc


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
    """Fit the slide model to each whole slide; rows of the ``_FIT_NAMES`` features.

    The slide model is the observable's response to the observed load's variation
    (a gain) plus the contact model driven by the travel. Fitted in two rounds: the
    gain by least squares, the contact model on what it leaves; then the gain again
    on what the contact model leaves, and the contact model again from its first
    fit. ``contact_fit_r2`` is the R^2 of both on the observable, ``contact_law_r2``
    the contact model's on what the load leaves. Recordings are batched by speed (one
    :func:`~frictionfit.fit.fit_trials` call per speed and round). A fit that fails
    keeps its values and gets ``contact_fit_ok = 0``; a non-finite value is replaced by
    the parameter's default (and flagged the same way).
    """
    from frictionfit.fit import fit_trials

    windows = list(_fit_windows(recordings))
    out = np.empty((len(windows), len(_FIT_NAMES)))
    for speed in sorted({w[0] for w in windows}):
        idx = [i for i, w in enumerate(windows) if w[0] == speed]
        t = windows[idx[0]][1]
        y = np.vstack([windows[i][2] for i in idx])
        n = np.vstack([windows[i][3] for i in idx])
        x = np.vstack([windows[i][4] for i in idx])
        rest = y - np.vstack([_load_term(yi, ni) for yi, ni in zip(y, n, strict=True)])
        guesses = [_start_guess(ri, xi, t[-1]) for ri, xi in zip(rest, x, strict=True)]
        sign = np.asarray([g[1] for g in guesses])
        # flat in slip_length: its default prior is sized for a rubbing stroke, not a slide
        kw = {"model": CONTACT_MODEL, "drive": "given", "direction": sign,
              "max_steps": max_steps, "priors": {"slip_length": None}}
        res = fit_trials(rest, t, x, u0=np.asarray([g[0] for g in guesses]), **kw)
        law = np.vstack([res.predict(r, t) for r in range(len(idx))])
        rest = y - np.vstack([_load_term(yi - li, ni)
                              for yi, li, ni in zip(y, law, n, strict=True)])
        res = fit_trials(rest, t, x, u0=np.asarray(res.u), **kw)
        law = np.vstack([res.predict(r, t) for r in range(len(idx))])
        total_r2 = 1.0 - ((rest - law) ** 2).sum(axis=1) / ((y - y.mean(axis=1, keepdims=True))
                                                            ** 2).sum(axis=1)
        for row, i in enumerate(idx):
            out[i] = _fit_row(res, row, sign[row], total_r2[row], windows[i][5])
    out[:, :4] = np.log(out[:, :4])
    return out


def _fit_row(res, row: int, sign: float, total_r2: float, span: float) -> np.ndarray:
    """One slide's ``_FIT_NAMES`` values (the first four not yet logged) from its fit."""
    v, se = res.params(row), res.stderrs(row)
    log_k_se = se["k"] / v["k"] if np.isfinite(se["k"]) and v["k"] > 0 else 10.0
    law_r2 = float(res.r2[row])
    vals = [v["k"], 1.0 + v["f_static_excess"] / v["f_kin"], v["slip_length"], v["tau"],
            v["relax_frac"], min(log_k_se, 10.0), sign, total_r2,
            float(res.status[row] == Status.CONVERGED), np.log(span), law_r2]
    vals = np.asarray(vals, dtype=np.float64)
    if not np.all(np.isfinite(vals)):
        vals = np.where(np.isfinite(vals), vals, 1.0)
        vals[8] = 0.0
    return vals


class SlidingPhysicalFeatures(RecordingFeatures):
    """Slide-model fit and stick-slip statistics of FabricSlide slides, beyond the grip.

    Blind to the proximity words; with ``grip="stroke"`` (the default), ``"breakaway"``
    or ``"none"`` every value is unchanged by a constant offset on any taxel (see the
    module docstring for the definitions and units). Stiffness, ratio, slip length and
    relaxation time are given as natural logs. Unless ``grip="none"``, each feature is
    brought to the training data's reference load by a power law of a measure of the
    load, its exponent fitted within the classes across the training grips
    (:class:`~frictionfit.features.grip.GripLaw`); ``fit`` then needs the classes ``y``
    (without them the exponents are zero).

    Parameters
    ----------
    max_steps : int, default 200
        Solver steps per contact-model fit.
    contact : bool, default False
        Also give the slide model's fitted parameters and fit statistics (``_FIT_NAMES``)
        as features; they are always computed (and cached), so switching costs no fit.
    grip : {"stroke", "breakaway", "scaled", "none"}, default "stroke"
        The measure of the load the features' laws are fitted against: the stroke
        shift or the breakaway shift (counts; offset-invariant), the grip load (counts;
        the taxels' level, not offset-invariant); or none (the features as observed).
    cache : bool, default True
        Cache rows per recording content (see :mod:`frictionfit.features._base`).

    Attributes
    ----------
    grip_law_ : GripLaw or None
        The fitted exponents (``grip_law_.exponents_``, one per feature); None with
        ``grip="none"``.
    """

    _version = 4
    _view_params = ("contact", "grip")

    def __init__(self, max_steps: int = 200, contact: bool = False, grip: str = "stroke",
                 cache: bool = True):
        self.max_steps = max_steps
        self.contact = contact
        self.grip = grip
        self.cache = cache

    def fit(self, X: Sequence[Recording], y=None) -> SlidingPhysicalFeatures:
        self.fit_transform(X, y)
        return self

    def fit_transform(self, X: Sequence[Recording], y=None, **fit_params) -> np.ndarray:
        if self.grip not in GRIP_MEASURES:
            raise ValueError(f"grip={self.grip!r}; choose from {list(GRIP_MEASURES)}")
        X = list(X)
        rows = self._filled_rows(X, fit=True)
        self.grip_law_ = None
        if self.grip != "none":
            log_load = _log_loads(X, self.grip)
            self.grip_law_ = GripLaw().fit(rows, y, log_load=log_load)
            return self.grip_law_.transform(rows, log_load=log_load)
        return rows

    def transform(self, X: Sequence[Recording]) -> np.ndarray:
        check_is_fitted(self, "fill_values_")
        X = list(X)
        rows = self._filled_rows(X, fit=False)
        if getattr(self, "grip_law_", None) is None:
            return rows
        return self.grip_law_.transform(rows, log_load=_log_loads(X, self.grip))

    def _filled_rows(self, X: list[Recording], fit: bool) -> np.ndarray:
        rows = self._rows(X)
        if fit:
            self._fit_rows(rows, X)
        return self._filled(rows, X)

    def _extract(self, recordings: Sequence[Recording]) -> np.ndarray:
        steady = np.vstack([steady_features(r) for r in recordings])
        return np.hstack([fit_breakaway(recordings, self.max_steps), steady])

    def _stored_names(self) -> list[str]:
        fit = [f"sliding:log_{n}" if i < 4 else f"sliding:{n}" for i, n in enumerate(_FIT_NAMES)]
        amp = [f"sliding:amplitude_share:{c} [log]" for c in TAXELS]
        bands = [f"sliding:band_{lo:.3g}-{hi:.3g}Hz:{c} [log share]"
                 for lo, hi in BANDS_HZ for c in TAXELS]
        return fit + [f"sliding:{n}" for n in _CYCLE_NAMES] + amp + bands

    def _names(self) -> list[str]:
        names = self._stored_names()
        return names if self.contact else names[len(_FIT_NAMES):]


def _log_loads(recordings: Sequence[Recording], grip: str) -> np.ndarray:
    return np.log([GRIP_MEASURES[grip](r) for r in recordings])
