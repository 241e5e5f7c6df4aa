"""Baseline B: FFT-bin features of the raw signals right after each movement command.

Per motion, for each movement command (``out``, ``back``) and each force channel:
the raw (unfiltered) samples in a ``window_s`` = 150 ms window starting at the
command (NaN gaps linearly interpolated), their single-sided amplitude spectrum
(``|rfft| / n``, doubled except at DC and Nyquist; N), split into ``n_bins`` = 10
contiguous groups of frequencies (``numpy.array_split``) and averaged per group:
2 windows x 4 channels x 10 bins = 80 features per motion. A measurement's features
are the medians over its non-preparatory motions.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from frictionfit.errors import RecordingError
from frictionfit.features._base import FeatureWarning, RecordingFeatures, median_over_motions
from frictionfit.features._rubbing import (
    PHASES,
    RUBBING_CHANNELS,
    channel_samples,
    command_times,
    fill_gaps,
    motions,
)
from frictionfit.recording import Recording

__all__ = ["FFTBinFeatures", "amplitude_bins"]


def amplitude_bins(x: np.ndarray, n_bins: int) -> np.ndarray:
    """Mean single-sided amplitude (N) in ``n_bins`` frequency groups of one window ``x``."""
    n = x.shape[0]
    amp = np.abs(np.fft.rfft(x)) / n
    amp[1:(n + 1) // 2] *= 2.0  # every bin but DC (and Nyquist, for even n) has a mirror
    return np.array([b.mean() for b in np.array_split(amp, n_bins)])


class FFTBinFeatures(RecordingFeatures):
    """Baseline B: binned amplitude spectra of 150-ms windows after each command.

    Parameters
    ----------
    window_s : float, default 0.15
        Window length after each command, s.
    n_bins : int, default 10
        Frequency groups per window and channel.
    channels : tuple of str
        Force channels to use, by name.
    cache : bool, default True
        Cache rows by recording content.

    Examples
    --------
    >>> len(FFTBinFeatures().get_feature_names_out())
    80
    """

    def __init__(self, window_s: float = 0.15, n_bins: int = 10,
                 channels: tuple[str, ...] = RUBBING_CHANNELS, cache: bool = True):
        self.window_s = window_s
        self.n_bins = n_bins
        self.channels = channels
        self.cache = cache

    def _names(self) -> list[str]:
        return [f"{ch}:{p}_fft_bin{b} [N]"
                for ch in self.channels for p in PHASES for b in range(self.n_bins)]

    def _extract(self, recordings: Sequence[Recording]) -> np.ndarray:
        out = np.full((len(recordings), len(self._names())), np.nan)
        for i, rec in enumerate(recordings):
            try:
                found = motions(rec, self.channels)
            except RecordingError as exc:
                warnings.warn(f"fftbins features: {exc}", FeatureWarning, stacklevel=2)
                continue
            rows = []
            for m in found:
                x = channel_samples(m, self.channels)
                n = int(round(self.window_s * m.sample_rate_hz))
                starts = {p: int(round(s * m.sample_rate_hz)) for p, s in command_times(m).items()}
                windows = {p: fill_gaps(x[s:s + n]) for p, s in starts.items()}
                rows.append(np.concatenate([
                    amplitude_bins(windows[p][:, j], self.n_bins)
                    for j in range(x.shape[1]) for p in PHASES
                ]))
            out[i] = median_over_motions(rows)
        return out
