"""Baseline D: the truncated, normalised raw signals, for a fully connected network.

Per motion: the first ``n_samples`` = 1900 raw samples of each force channel from
the motion start (50 ms before the ``out`` command), NaN gaps linearly
interpolated, each channel minus its baseline (the median before the ``out``
command), so the day-to-day sensor offsets are gone; the pipeline's scaler then
standardises every sample position. A measurement's row is the median waveform over
its non-preparatory motions, flattened channel by channel: 1900 x 4 = 7600 features
(``step`` > 1 keeps every ``step``-th sample).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from frictionfit.errors import RecordingError
from frictionfit.features._base import FeatureWarning, RecordingFeatures, median_over_motions
from frictionfit.features._rubbing import (
    RUBBING_CHANNELS,
    channel_samples,
    fill_gaps,
    motions,
)
from frictionfit.recording import Recording
from frictionfit.segmentation import Motion

__all__ = ["RawSignalFeatures", "normalised_signal"]


def normalised_signal(m: Motion, channels: Sequence[str], n_samples: int) -> np.ndarray:
    """First ``n_samples`` of each channel minus its pre-command median (N), gaps filled."""
    x = fill_gaps(channel_samples(m, channels)[:n_samples])
    if x.shape[0] < n_samples:
        raise RecordingError(f"motion {m.index} has {x.shape[0]} samples, fewer than "
                             f"n_samples={n_samples}", path=m.recording)
    pre = x[: max(int(round(m.t_out * m.sample_rate_hz)), 1)]
    return x - np.median(pre, axis=0)


class RawSignalFeatures(RecordingFeatures):
    """Baseline D: baseline-subtracted raw waveforms (N), 1900 samples x 4 channels.

    Parameters
    ----------
    n_samples : int, default 1900
        Samples kept per channel from the motion start.
    step : int, default 1
        Keep every ``step``-th of them.
    channels : tuple of str
        Force channels to use, by name.
    cache : bool, default True
        Cache rows by recording content.

    Examples
    --------
    >>> RawSignalFeatures(n_samples=4, step=2).get_feature_names_out()[:2].tolist()
    ['thumb_x:t0.000 [N]', 'thumb_x:t0.002 [N]']
    """

    def __init__(self, n_samples: int = 1900, step: int = 1,
                 channels: tuple[str, ...] = RUBBING_CHANNELS, cache: bool = True):
        self.n_samples = n_samples
        self.step = step
        self.channels = channels
        self.cache = cache

    def _names(self) -> list[str]:
        # Sample times assume the rig's 1000 Hz; the index is what matters.
        return [f"{ch}:t{k / 1000:.3f} [N]"
                for ch in self.channels for k in range(0, self.n_samples, self.step)]

    def _extract(self, recordings: Sequence[Recording]) -> np.ndarray:
        out = np.full((len(recordings), len(self._names())), np.nan)
        for i, rec in enumerate(recordings):
            try:
                waves = [normalised_signal(m, self.channels, self.n_samples)
                         for m in motions(rec, self.channels)]
            except RecordingError as exc:
                warnings.warn(f"raw features: {exc}", FeatureWarning, stacklevel=2)
                continue
            out[i] = median_over_motions(waves)[:: self.step].T.ravel()
        return out
