"""The published gesture-skin features: frame descriptors, their statistics and wavelet bands.

For one gesture (frames of a pressure matrix, time x rows x cols):

1. each frame is upsampled 2x by bicubic spline interpolation (20 x 20 -> 40 x 40;
   the same as ``scipy.ndimage.zoom(frame, 2, order=3)``, applied as two small
   matrix products so all frames go at once);
2. six **descriptors** per frame (:data:`DESCRIPTORS`): mean, max and standard
   deviation of all pixels (kPa), distance of the centre of pressure and of the
   maximum from the frame centre (upsampled pixels), and the number of pixels above
   mean + std;
3. per descriptor sequence, six **statistics** (:data:`SEQUENCE_STATS`): mean, std,
   variance, max - min, kurtosis, skewness -> 6 x 6 = 36 features;
4. per descriptor sequence, a 10-level fast wavelet transform with the Daubechies-8
   wavelet (PyWavelets, periodization mode) gives 11 sub-bands: details d1..d10 and
   the approximation a10. A band of a 3-s gesture (150 frames) holds
   ceil(150 / 2**j) coefficients: d1..d7 have 75, 38, 19, 10, 5, 3, 2; d8, d9, d10 and
   a10 have a single one, too short for a spread or shape. So d1..d7 get five
   statistics (mean, std, variance, kurtosis, skewness) and d8..d10, a10 the mean
   only -> 6 x (7 x 5 + 4) = 234 features.

Total: 36 + 234 = **270** features per gesture. The band layout is fixed, so every
gesture yields the same 270 columns: sequences shorter than ``min_frames`` (default
150) are padded with their last value before the transform (with periodization any
length from 129 frames on gives the layout above; longer ones simply put more
coefficients into the mean-only bands).

Conventions: std and variance are population values (ddof=0); kurtosis is the
excess (Fisher) kurtosis and skewness the biased moment ratio, as in
``scipy.stats.kurtosis`` / ``skew`` with their defaults; for a constant sequence
both are 0 (not NaN). The centre of pressure uses the pressure clipped at 0
(bicubic overshoot is not pressure); a frame without pressure has both distances 0.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Sequence

import numpy as np
import pywt
from scipy import ndimage
from sklearn.base import BaseEstimator, TransformerMixin

from frictionfit.datasets.gesture_skin import frames_of
from frictionfit.recording import Recording

__all__ = [
    "DESCRIPTORS",
    "N_FEATURES",
    "SEQUENCE_STATS",
    "GestureFeatures",
    "band_stats",
    "frame_descriptors",
    "gesture_feature_names",
    "gesture_features",
    "sequence_stats",
    "upsample",
]

DESCRIPTORS = ("mean", "max", "std", "cop_dist", "peak_dist", "n_above")
SEQUENCE_STATS = ("mean", "std", "var", "range", "kurtosis", "skewness")
BAND_STATS = ("mean", "std", "var", "kurtosis", "skewness")
WAVELET = "db8"
LEVELS = 10
#: Detail levels that get all five band statistics; the rest (and a10) get the mean.
FULL_LEVELS = 7
N_FEATURES = len(DESCRIPTORS) * (
    len(SEQUENCE_STATS) + FULL_LEVELS * len(BAND_STATS) + (LEVELS - FULL_LEVELS + 1)
)
assert N_FEATURES == 270


@functools.lru_cache(maxsize=16)
def _zoom_matrix(n: int, factor: int) -> np.ndarray:
    """The (n * factor, n) matrix of 1-D cubic-spline zoom (``ndimage.zoom`` order 3)."""
    eye = np.eye(n)
    m = np.stack([ndimage.zoom(eye[:, j], factor, order=3) for j in range(n)], axis=1)
    m.setflags(write=False)
    return m


def upsample(frames: np.ndarray, factor: int = 2) -> np.ndarray:
    """Bicubic spline upsampling of every frame: (T, R, C) -> (T, factor R, factor C).

    Equal to ``scipy.ndimage.zoom(frame, factor, order=3)`` frame by frame (the cubic
    spline is separable, so it is ``A @ frame @ B.T`` with fixed matrices).
    """
    frames = np.asarray(frames, dtype=np.float64)
    a = _zoom_matrix(frames.shape[1], factor)
    b = _zoom_matrix(frames.shape[2], factor)
    return np.matmul(np.matmul(a, frames), b.T)


def frame_descriptors(frames: np.ndarray) -> np.ndarray:
    """The six descriptors of each frame, shape (6, T), in the order of :data:`DESCRIPTORS`.

    ``frames`` are the (already upsampled) frames, (T, H, W). Distances are in pixels
    from the frame centre ((H - 1) / 2, (W - 1) / 2); ``n_above`` counts pixels strictly
    above the frame's mean + std.
    """
    n, h, w = frames.shape
    flat = frames.reshape(n, h * w)
    mean = flat.mean(axis=1)
    peak = flat.max(axis=1)
    std = flat.std(axis=1)
    rows = np.repeat(np.arange(h, dtype=np.float64), w) - (h - 1) / 2
    cols = np.tile(np.arange(w, dtype=np.float64), h) - (w - 1) / 2
    weights = np.clip(flat, 0.0, None)
    total = weights.sum(axis=1)
    safe = np.where(total > 0, total, 1.0)
    cop_r = weights @ rows / safe
    cop_c = weights @ cols / safe
    cop_dist = np.where(total > 0, np.hypot(cop_r, cop_c), 0.0)
    k = flat.argmax(axis=1)
    peak_dist = np.where(peak > 0, np.hypot(rows[k], cols[k]), 0.0)
    n_above = (flat > (mean + std)[:, None]).sum(axis=1).astype(np.float64)
    return np.stack([mean, peak, std, cop_dist, peak_dist, n_above])


def _moments(x: np.ndarray) -> tuple[np.ndarray, ...]:
    """Mean, variance, skewness, excess kurtosis along the last axis (0 shape if constant)."""
    mean = x.mean(axis=-1)
    d = x - mean[..., None]
    m2 = (d * d).mean(axis=-1)
    m3 = (d**3).mean(axis=-1)
    m4 = (d**4).mean(axis=-1)
    # relative tolerance: variance at rounding level counts as constant
    flat = m2 <= (1e-12 * np.maximum(np.abs(mean), 1.0)) ** 2
    safe = np.where(flat, 1.0, m2)
    skew = np.where(flat, 0.0, m3 / safe**1.5)
    kurt = np.where(flat, 0.0, m4 / safe**2 - 3.0)
    return mean, m2, skew, kurt


def sequence_stats(seq: np.ndarray) -> np.ndarray:
    """Mean, std, variance, max - min, kurtosis, skewness of each row: (D, T) -> (D, 6)."""
    mean, var, skew, kurt = _moments(seq)
    rng = seq.max(axis=-1) - seq.min(axis=-1)
    return np.stack([mean, np.sqrt(var), var, rng, kurt, skew], axis=-1)


def band_stats(seq: np.ndarray, min_frames: int = 150) -> np.ndarray:
    """Wavelet sub-band statistics of each row: (D, T) -> (D, 39).

    Order per row: for d1..d7, (mean, std, var, kurtosis, skewness); then the means
    of d8, d9, d10 and a10.
    """
    n = seq.shape[-1]
    if n < min_frames:
        seq = np.concatenate([seq, np.repeat(seq[:, -1:], min_frames - n, axis=1)], axis=1)
    with warnings.catch_warnings():
        # 10 levels exceed pywt's "useful" level for short sequences: intended here.
        warnings.filterwarnings("ignore", message="Level value of", category=UserWarning)
        coeffs = pywt.wavedec(seq, WAVELET, mode="periodization", level=LEVELS, axis=-1)
    details = coeffs[:0:-1]  # d1 .. d10
    out = []
    for band in details[:FULL_LEVELS]:
        mean, var, skew, kurt = _moments(band)
        out.append(np.stack([mean, np.sqrt(var), var, kurt, skew], axis=-1))
    out.append(np.stack([b.mean(axis=-1) for b in [*details[FULL_LEVELS:], coeffs[0]]], axis=-1))
    return np.concatenate(out, axis=-1)


def gesture_features(
    frames: np.ndarray, rate_hz: float = 50.0, *, min_frames: int = 150
) -> np.ndarray:
    """The 270 published features of one gesture.

    Parameters
    ----------
    frames : ndarray of shape (T, rows, cols)
        Pressure frames (kPa, or normalised), e.g. (150, 20, 20) for 3 s at 50 frames/s.
    rate_hz : float, default 50
        Frame rate in Hz; only checked (the published features are per frame).
    min_frames : int, default 150
        Shorter sequences are padded with their last value before the wavelet transform.

    Returns
    -------
    ndarray of shape (270,)
        In the order of :func:`gesture_feature_names`.

    Examples
    --------
    >>> import numpy as np
    >>> gesture_features(np.random.default_rng(0).random((150, 20, 20))).shape
    (270,)
    """
    frames = check_frames(frames, rate_hz, min_time=2)
    desc = frame_descriptors(upsample(frames))
    return np.concatenate([sequence_stats(desc), band_stats(desc, min_frames)], axis=1).ravel()


def check_frames(frames, rate_hz: float, min_time: int = 1) -> np.ndarray:
    """``frames`` as float64 (time, rows, cols); ValueError naming the problem otherwise."""
    p = np.asarray(frames, dtype=np.float64)
    if p.ndim != 3 or p.shape[0] < min_time:
        shape = "(time, rows, cols)" if min_time <= 1 else f"(time >= {min_time}, rows, cols)"
        raise ValueError(f"frames must be {shape}, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"frames hold {int((~np.isfinite(p)).sum())} NaN/inf value(s)")
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be positive, got {rate_hz}")
    return p


def gesture_feature_names() -> list[str]:
    """Names of the 270 features, e.g. ``cop_dist__seq_kurtosis``, ``max__d3_std``."""
    per = [f"seq_{s}" for s in SEQUENCE_STATS]
    per += [f"d{j}_{s}" for j in range(1, FULL_LEVELS + 1) for s in BAND_STATS]
    per += [f"d{j}_mean" for j in range(FULL_LEVELS + 1, LEVELS + 1)] + [f"a{LEVELS}_mean"]
    return [f"{d}__{p}" for d in DESCRIPTORS for p in per]


class GestureFeatures(TransformerMixin, BaseEstimator):
    """The 270 published gesture-skin features of each recording (see the module notes).

    A stateless scikit-learn transformer over a list of gesture
    :class:`~frictionfit.recording.Recording` objects (taxel channels ``r{row}c{col}``).

    Parameters
    ----------
    min_frames : int, default 150
        Descriptor sequences shorter than this are padded with their last value before
        the 10-level wavelet transform.

    Attributes
    ----------
    n_features_in_ : int
        Always 1 (one recording per row).
    n_features_out_ : int
        270.

    Examples
    --------
    >>> import numpy as np
    >>> from frictionfit.datasets.gesture_skin import recording_from_frames
    >>> rec = recording_from_frames(np.ones((150, 20, 20)), 50.0, {"label": "press"})
    >>> GestureFeatures().fit_transform([rec]).shape
    (1, 270)
    """

    def __init__(self, min_frames: int = 150):
        self.min_frames = min_frames

    def fit(self, X: Sequence[Recording], y=None) -> GestureFeatures:
        self.n_features_in_ = 1
        self.n_features_out_ = N_FEATURES
        return self

    def transform(self, X: Sequence[Recording]) -> np.ndarray:
        out = np.empty((len(X), N_FEATURES))
        for i, rec in enumerate(X):
            try:
                out[i] = gesture_features(frames_of(rec), rec.sample_rate_hz,
                                          min_frames=self.min_frames)
            except ValueError as exc:
                raise ValueError(f"recording {rec.name!r}: {exc}") from None
        return out

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        return np.asarray(gesture_feature_names(), dtype=object)
