"""Baseline C: FFT-magnitude spectra, resampled, flattened, reduced by incremental PCA.

The FabricSlide paper's pipeline (Wang et al. 2022), read as the authors' code runs it:

1. normalise the recording (time x channels) with **one** mean and standard deviation
   over all its samples and channels (``norm="global"``, the default) -- or each
   channel by its own mean and sd (``norm="per_channel"``, the paper's wording);
2. FFT magnitude of every channel along time (``rfft``, orthonormal scaling), the
   zero-frequency bin dropped;
3. the magnitude spectrum resampled to ``n_resample`` points with FFT-based
   resampling (:func:`scipy.signal.resample`), independent of the recording length;
4. flattened frequency-major (``n_resample x n_channels`` values) and projected on
   ``n_components`` principal components by :class:`~sklearn.decomposition.IncrementalPCA`
   (``partial_fit`` adds recordings, or whole classes, later).

The global normalisation keeps part of the static load pattern over the taxels
(a taxel loaded more than the others keeps a larger spectrum), i.e. it can use the
mounting instead of the texture; ``norm="per_channel"`` removes every channel's
mean and scale. FabricSlide recordings use their 16 taxels only (never the
proximity words); other recordings use all their channels, with NaN gaps filled
by linear interpolation in time.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.signal import resample
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.decomposition import IncrementalPCA
from sklearn.utils.validation import check_is_fitted

from frictionfit.datasets.fabricslide import TAXELS
from frictionfit.errors import RecordingError
from frictionfit.features._base import _as_list
from frictionfit.recording import Recording

__all__ = ["NORMS", "SpectralPCAFeatures", "recording_spectrum", "spectrum", "texture_signals"]

NORMS = ("global", "per_channel")


def texture_signals(rec: Recording) -> np.ndarray:
    """The channels a texture feature may use, (time, channels), NaN gaps interpolated.

    FabricSlide recordings give their 16 taxels (counts); other recordings all channels.

    Raises
    ------
    RecordingError
        When a channel has fewer than two finite samples (naming it).
    """
    if rec.metadata.get("dataset") == "fabricslide":
        x = np.column_stack([rec.channel(c) for c in TAXELS])
        names = TAXELS
    else:
        x = rec.samples.copy()
        names = rec.channel_names
    for j, name in enumerate(names):
        ok = np.isfinite(x[:, j])
        if ok.all():
            continue
        if ok.sum() < 2:
            raise RecordingError("fewer than two finite samples", path=rec.name, channel=name)
        x[:, j] = np.interp(rec.t, rec.t[ok], x[ok, j])
    return x


def spectrum(x: np.ndarray, n_resample: int = 32, norm: str = "global") -> np.ndarray:
    """Resampled FFT magnitude of ``x`` (time, channels): shape (n_resample, channels).

    Parameters
    ----------
    x : ndarray (n_samples, n_channels)
        Signals in any unit (the normalisation makes the result unitless).
    n_resample : int
        Points of the resampled spectrum (the DC bin excluded).
    norm : {"global", "per_channel"}
        One mean/sd over the whole matrix, or one per channel (a flat channel gives 0).
    """
    if norm not in NORMS:
        raise ValueError(f"norm must be one of {NORMS}, not {norm!r}")
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[0] < 4:
        raise ValueError(f"need (time >= 4, channels) samples, got shape {x.shape}")
    axis = None if norm == "global" else 0
    sd = x.std(axis=axis, keepdims=True)
    z = (x - x.mean(axis=axis, keepdims=True)) / np.where(sd > 0, sd, 1.0)
    mag = np.abs(np.fft.rfft(z, axis=0, norm="ortho"))[1:]
    return resample(mag, n_resample, axis=0)


def recording_spectrum(rec: Recording, n_resample: int = 32, norm: str = "global") -> np.ndarray:
    """The flattened (frequency-major) spectrum of one recording's texture channels."""
    return spectrum(texture_signals(rec), n_resample, norm).ravel()


class SpectralPCAFeatures(TransformerMixin, BaseEstimator):
    """The FabricSlide paper's features: resampled FFT spectra projected by incremental PCA.

    Spectra are cheap (one FFT per recording), so they are not cached; the IPCA is
    the fitted state.

    Parameters
    ----------
    n_components : int, default 7
        Principal components kept (the paper uses up to 7).
    n_resample : int, default 32
        Points of each channel's resampled spectrum.
    norm : {"global", "per_channel"}, default "global"
        ``"global"``: one mean/sd per recording over all channels (the authors' code);
        ``"per_channel"``: each channel standardised (the paper's wording).

    Attributes
    ----------
    ipca_ : IncrementalPCA
        Fitted on the spectra of the training recordings.
    n_channels_ : int
        Channels per recording seen in ``fit`` (16 taxels for FabricSlide).

    Examples
    --------
    >>> import numpy as np
    >>> from frictionfit.recording import Recording
    >>> rng = np.random.default_rng(0)
    >>> recs = [Recording.from_arrays(rng.normal(size=(200, 4)), 100.0, list("abcd"))
    ...         for _ in range(6)]
    >>> SpectralPCAFeatures(n_components=3).fit_transform(recs).shape
    (6, 3)
    """

    def __init__(self, n_components: int = 7, n_resample: int = 32, norm: str = "global"):
        self.n_components = n_components
        self.n_resample = n_resample
        self.norm = norm

    def spectra(self, X: Sequence[Recording]) -> np.ndarray:
        """Flattened spectra, shape (n_recordings, n_resample * n_channels)."""
        recordings = _as_list(X)
        if not recordings:
            raise ValueError("no recordings given")
        rows = [recording_spectrum(r, self.n_resample, self.norm) for r in recordings]
        for rec, row in zip(recordings, rows, strict=True):
            if row.size != rows[0].size:
                raise RecordingError(
                    f"{row.size // self.n_resample} texture channels, but "
                    f"{recordings[0].name} has {rows[0].size // self.n_resample}: "
                    "every recording needs the same channels",
                    path=rec.name,
                )
        return np.vstack(rows)

    def partial_fit(self, X: Sequence[Recording], y=None) -> SpectralPCAFeatures:
        """Add recordings to the IPCA (e.g. a new class), keeping what was learnt."""
        s = self.spectra(X)
        if not hasattr(self, "ipca_"):
            self.ipca_ = IncrementalPCA(n_components=self.n_components)
            self.n_channels_ = s.shape[1] // self.n_resample
        elif s.shape[1] != self.n_channels_ * self.n_resample:
            raise ValueError(
                f"recordings have {s.shape[1] // self.n_resample} channels; "
                f"the IPCA was fitted on {self.n_channels_}"
            )
        self.ipca_.partial_fit(s)
        self.n_features_in_ = 1
        return self

    def fit(self, X: Sequence[Recording], y=None) -> SpectralPCAFeatures:
        """Fit the IPCA afresh on the spectra of ``X``."""
        for attr in ("ipca_", "n_channels_"):
            if hasattr(self, attr):
                delattr(self, attr)
        return self.partial_fit(X, y)

    def transform(self, X: Sequence[Recording]) -> np.ndarray:
        """Principal-component scores, shape (n_recordings, n_components)."""
        check_is_fitted(self, "ipca_")
        return self.ipca_.transform(self.spectra(X))

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        return np.asarray([f"spectral:pc{i + 1}" for i in range(self.n_components)], dtype=object)

