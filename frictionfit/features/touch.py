"""Interpretable physical features of a touch on a pressure-matrix skin.

Beside the published gesture features (:mod:`frictionfit.features.wavelet`), a few
numbers a person can read: how hard, how long, how large the touch was, how fast the
contact spread, how the force relaxed after a press, how often a scratch or stroke
repeated, how far the contact moved, and whether it converged (grab, pinch).

From the frames ``p`` (kPa; time x rows x cols) at ``rate_hz`` and pitch ``pitch_cm``:

- contact taxels: ``p > contact_kpa``; contact area ``A(t)`` = their number x pitch²
  (cm²); the touch lasts while ``A > 0``;
- normal force ``F(t)`` = sum of ``p`` over contact taxels x pitch² x 0.1 (N; 1 kPa
  on 1 cm² is 0.1 N). With normalised readings (unit ``"1"``) the force is in
  reading x cm² x 0.1, not N;
- centre of pressure (CoP, cm) and radius of gyration (cm) of the contact taxels.

=====================  =====  ==============================================================
feature                unit   definition
=====================  =====  ==============================================================
peak_force_n           N      max F
contact_s              s      number of frames in contact / rate
max_area_cm2           cm²    max A
area_growth_cm2_s      cm²/s  10-90 % rise of A before its maximum: 0.8 max A / (t90 - t10)
relaxation_s           s      after the force peak, the time for F to fall 1/e of the way to
                              its hold plateau: F (0.1-s moving average) where it is
                              flattest between the peak and the release (F < 0.1 x peak);
                              0 when F drops less than ``min_relax_drop`` x peak (no
                              relaxation)
repetition_hz          Hz     dominant frequency (>= ``min_repetition_hz``) of the CoP
                              motion along its main axis during contact; 0 if the touch
                              is shorter than 8 frames
cop_range_cm           cm     extent of the CoP along its main axis during contact
cop_path_cm            cm     length of the CoP path during contact
spread_ratio           1      radius of gyration at the force peak / at the first frame
                              with F >= 0.2 x peak (< 1: the contact converged)
=====================  =====  ==============================================================

No feature is ever NaN: an untouched recording gives zeros (and spread_ratio 1).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin

from frictionfit.datasets.gesture_skin import frames_of
from frictionfit.features.wavelet import check_frames
from frictionfit.recording import Recording

__all__ = ["TOUCH_FEATURES", "TouchPhysicalFeatures", "touch_features"]

TOUCH_FEATURES = (
    "peak_force_n",
    "contact_s",
    "max_area_cm2",
    "area_growth_cm2_s",
    "relaxation_s",
    "repetition_hz",
    "cop_range_cm",
    "cop_path_cm",
    "spread_ratio",
)
#: 1 kPa acting on 1 cm² is 0.1 N.
_KPA_CM2_TO_N = 0.1
#: The hold after a press ends (release) when the force falls below this fraction of its peak.
_RELEASE_FRAC = 0.1


def _rise_rate(area: np.ndarray, rate_hz: float) -> float:
    top = area.max()
    if top <= 0:
        return 0.0
    k = int(area.argmax())
    head = area[: k + 1]
    i10 = int(np.argmax(head >= 0.1 * top))
    i90 = int(np.argmax(head >= 0.9 * top))
    return float(0.8 * top / max((i90 - i10) / rate_hz, 1.0 / rate_hz))


def _relaxation(force: np.ndarray, rate_hz: float, min_drop: float) -> float:
    peak = force.max()
    if peak <= 0:
        return 0.0
    k = int(force.argmax())
    after = force[k:]
    below = np.flatnonzero(after < _RELEASE_FRAC * peak)
    hold = after[: int(below[0]) if below.size else after.size]
    width = max(3, int(round(0.1 * rate_hz)))
    if hold.size < width + 2:
        return 0.0
    smooth = np.convolve(hold, np.ones(width) / width, mode="valid")
    flattest = int(np.argmin(np.abs(np.gradient(smooth))[1:])) + 1
    plateau = float(smooth[flattest])
    drop = peak - plateau
    if drop < min_drop * peak:
        return 0.0
    level = plateau + drop / np.e
    j = int(np.argmax(hold <= level))  # hold[0] = peak > level, so j >= 1 when found
    if hold[j] > level:
        return 0.0
    frac = (hold[j - 1] - level) / (hold[j - 1] - hold[j])  # linear interpolation
    return float((j - 1 + frac) / rate_hz)


def _repetition(cop: np.ndarray, rate_hz: float, min_hz: float) -> tuple[float, float]:
    """Dominant frequency (Hz) and extent (cm) of the CoP along its main axis."""
    if cop.shape[0] < 2:
        return 0.0, 0.0
    centred = cop - cop.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    x = centred @ vt[0]
    extent = float(x.max() - x.min())
    n = x.size
    if n < 8:
        return 0.0, extent
    tt = np.arange(n)
    x = x - np.polyval(np.polyfit(tt, x, 1), tt)
    nfft = max(512, 1 << int(np.ceil(np.log2(n))))
    power = np.abs(np.fft.rfft(x * np.hanning(n), nfft)) ** 2
    freqs = np.fft.rfftfreq(nfft, 1.0 / rate_hz)
    band = freqs >= min_hz
    if not band.any() or power[band].max() <= 0:
        return 0.0, extent
    return float(freqs[band][np.argmax(power[band])]), extent


def touch_features(
    frames: np.ndarray,
    rate_hz: float,
    *,
    pitch_cm: float = 1.0,
    contact_kpa: float = 2.0,
    min_relax_drop: float = 0.1,
    min_repetition_hz: float = 0.5,
) -> np.ndarray:
    """The physical touch features of one gesture, in the order of :data:`TOUCH_FEATURES`.

    Parameters
    ----------
    frames : ndarray of shape (T, rows, cols)
        Taxel pressures in kPa.
    rate_hz : float
        Frame rate, Hz.
    pitch_cm : float, default 1.0
        Taxel pitch, cm.
    contact_kpa : float, default 2.0
        A taxel is in contact above this pressure, kPa (well above the noise).
    min_relax_drop : float, default 0.1
        Smallest relative force drop after the peak that counts as relaxation.
    min_repetition_hz : float, default 0.5
        Lowest repetition frequency considered, Hz.

    Returns
    -------
    ndarray of shape (9,)

    Examples
    --------
    >>> import numpy as np
    >>> frames = np.zeros((10, 3, 3)); frames[2:6, 1, 1] = 50.0
    >>> touch_features(frames, 50.0)[:3].round(2).tolist()  # N, s, cm²
    [5.0, 0.08, 1.0]
    """
    p = check_frames(frames, rate_hz)
    n, rows, cols = p.shape
    flat = p.reshape(n, rows * cols)
    contact = flat > contact_kpa
    w = np.where(contact, flat, 0.0)
    cell = pitch_cm**2
    force = w.sum(axis=1) * cell * _KPA_CM2_TO_N
    area = contact.sum(axis=1) * cell
    touching = area > 0
    if not touching.any():
        return np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    y = np.repeat(np.arange(rows, dtype=np.float64), cols) * pitch_cm
    x = np.tile(np.arange(cols, dtype=np.float64), rows) * pitch_cm
    total = np.where(touching, w.sum(axis=1), 1.0)
    cop = np.stack([w @ x / total, w @ y / total], axis=1)
    gyr2 = (w @ (x * x) + w @ (y * y)) / total - (cop**2).sum(axis=1)
    gyration = np.sqrt(np.clip(gyr2, 0.0, None))
    path = cop[touching]
    cop_path = float(np.hypot(*np.diff(path, axis=0).T).sum()) if path.shape[0] > 1 else 0.0
    freq, extent = _repetition(path, rate_hz, min_repetition_hz)
    k = int(force.argmax())
    first = int(np.argmax(force >= 0.2 * force[k]))
    spread = float(gyration[k] / gyration[first]) if gyration[first] > 0 else 1.0
    return np.array([
        force.max(),
        touching.sum() / rate_hz,
        area.max(),
        _rise_rate(area, rate_hz),
        _relaxation(force, rate_hz, min_relax_drop),
        freq,
        extent,
        cop_path,
        spread,
    ])


class TouchPhysicalFeatures(TransformerMixin, BaseEstimator):
    """Interpretable physical features of each gesture recording (see the module notes).

    A stateless scikit-learn transformer over a list of gesture recordings (taxel
    channels ``r{row}c{col}``); the parameters are those of :func:`touch_features`.

    Examples
    --------
    >>> import numpy as np
    >>> from frictionfit.datasets.gesture_skin import recording_from_frames
    >>> rec = recording_from_frames(np.zeros((20, 4, 4)), 50.0, {"label": "none"})
    >>> TouchPhysicalFeatures().fit_transform([rec]).shape
    (1, 9)
    """

    def __init__(
        self,
        pitch_cm: float = 1.0,
        contact_kpa: float = 2.0,
        min_relax_drop: float = 0.1,
        min_repetition_hz: float = 0.5,
    ):
        self.pitch_cm = pitch_cm
        self.contact_kpa = contact_kpa
        self.min_relax_drop = min_relax_drop
        self.min_repetition_hz = min_repetition_hz

    def fit(self, X: Sequence[Recording], y=None) -> TouchPhysicalFeatures:
        self.n_features_in_ = 1
        return self

    def transform(self, X: Sequence[Recording]) -> np.ndarray:
        out = np.empty((len(X), len(TOUCH_FEATURES)))
        for i, rec in enumerate(X):
            try:
                out[i] = touch_features(
                    frames_of(rec),
                    rec.sample_rate_hz,
                    pitch_cm=self.pitch_cm,
                    contact_kpa=self.contact_kpa,
                    min_relax_drop=self.min_relax_drop,
                    min_repetition_hz=self.min_repetition_hz,
                )
            except ValueError as exc:
                raise ValueError(f"recording {rec.name!r}: {exc}") from None
        return out

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        return np.asarray(TOUCH_FEATURES, dtype=object)
