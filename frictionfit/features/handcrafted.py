"""Baseline A: the published hand-crafted rubbing features.

Per motion, after a centred moving average of ``filter_n`` = 9 samples, for each force
channel and each movement phase (``out``: from the ``move p2`` command; ``back``: from
the ``move p1`` command), with ``x0`` the value at the command:

- ``peak`` (N): the value farthest from ``x0`` within ``peak_window_s`` after the
  command (the peak during or just after the movement, of either sign);
- ``t_peak`` (s): time from the command to that peak;
- ``max_gradient`` (N/s): the largest absolute slope from the peak to the end of the
  phase's relaxation (the next command, or the end of the motion);
- ``static`` (N): the last value of that relaxation;

and per channel the ``start`` and ``end`` values of the motion (N). That is 10
features per channel (8 without the two ``t_peak``), 40 (32) for the rig's four
channels. A measurement's features are the medians over its non-preparatory motions
(NaN samples ignored). Offsets are kept, as published: these features see the
sensors' day-to-day drift.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from frictionfit.errors import RecordingError
from frictionfit.features._base import FeatureWarning, RecordingFeatures
from frictionfit.features._rubbing import (
    PHASES,
    RUBBING_CHANNELS,
    channel_samples,
    command_times,
    motions,
)
from frictionfit.recording import Recording
from frictionfit.segmentation import Motion

__all__ = ["HandcraftedFeatures", "phase_features"]

PHASE_FEATURES = (("peak", "N"), ("t_peak", "s"), ("max_gradient", "N/s"), ("static", "N"))


def phase_features(x: np.ndarray, rate_hz: float, i_cmd: int, i_end: int,
                   peak_samples: int) -> tuple[float, float, float, float]:
    """``(peak N, t_peak s, max_gradient N/s, static N)`` of one phase of one channel.

    ``x`` is the filtered signal of the motion (NaN where missing), ``i_cmd`` the
    sample of the command, ``i_end`` the end of the phase (exclusive) and
    ``peak_samples`` the length of the peak search window. NaN where the window
    holds no finite sample.
    """
    finite = np.flatnonzero(np.isfinite(x[i_cmd:i_end])) + i_cmd
    if finite.size == 0:
        return (np.nan,) * 4
    x0 = x[finite[0]]
    window = finite[finite < i_cmd + peak_samples]
    if window.size == 0:
        return (np.nan, np.nan, np.nan, float(x[finite[-1]]))
    i_peak = window[np.argmax(np.abs(x[window] - x0))]
    after = x[i_peak:i_end]
    slope = np.diff(after) * rate_hz
    slope = slope[np.isfinite(slope)]
    gradient = float(np.max(np.abs(slope))) if slope.size else np.nan
    return float(x[i_peak]), (i_peak - i_cmd) / rate_hz, gradient, float(x[finite[-1]])


class HandcraftedFeatures(RecordingFeatures):
    """Baseline A: peaks, times to peak, relaxation gradients, static and end values.

    Parameters
    ----------
    with_time : bool, default True
        Include the two ``t_peak`` features per channel.
    filter_n : int, default 9
        Moving-average length applied first (the published value).
    peak_window_s : float, default 0.3
        Peak search window after each command, s (movement ~0.15 s plus the overshoot).
    channels : tuple of str
        Force channels to use, by name.
    cache : bool, default True
        Cache rows by recording content (see :mod:`frictionfit.features._base`).

    Examples
    --------
    >>> HandcraftedFeatures(with_time=False).get_feature_names_out()[:2].tolist()
    ['thumb_x:out_peak [N]', 'thumb_x:out_max_gradient [N/s]']
    """

    def __init__(self, with_time: bool = True, filter_n: int = 9, peak_window_s: float = 0.3,
                 channels: tuple[str, ...] = RUBBING_CHANNELS, cache: bool = True):
        self.with_time = with_time
        self.filter_n = filter_n
        self.peak_window_s = peak_window_s
        self.channels = channels
        self.cache = cache

    def _kept(self) -> list[str]:
        return [n for n, _ in PHASE_FEATURES if self.with_time or n != "t_peak"]

    def _names(self) -> list[str]:
        units = dict(PHASE_FEATURES)
        names = []
        for ch in self.channels:
            names += [f"{ch}:{p}_{n} [{units[n]}]" for p in PHASES for n in self._kept()]
            names += [f"{ch}:start [N]", f"{ch}:end [N]"]
        return names

    def _motion_row(self, m: Motion) -> np.ndarray:
        x = channel_samples(m, self.channels)
        rate = m.sample_rate_hz
        cmd = {p: int(round(s * rate)) for p, s in command_times(m).items()}
        ends = {"out": cmd["back"], "back": x.shape[0]}
        keep = [i for i, (n, _) in enumerate(PHASE_FEATURES) if n in self._kept()]
        row = []
        for j in range(x.shape[1]):
            for p in PHASES:
                f = phase_features(x[:, j], rate, cmd[p], ends[p],
                                   int(round(self.peak_window_s * rate)))
                row += [f[i] for i in keep]
            ok = np.flatnonzero(np.isfinite(x[:, j]))
            row += [x[ok[0], j], x[ok[-1], j]] if ok.size else [np.nan, np.nan]
        return np.asarray(row, dtype=np.float64)

    def _motion_rows(self, recordings: Sequence[Recording]) -> list[np.ndarray | None]:
        out: list[np.ndarray | None] = []
        for rec in recordings:
            try:
                found = motions(rec, self.channels, self.filter_n)
            except RecordingError as exc:
                warnings.warn(f"handcrafted features: {exc}", FeatureWarning, stacklevel=2)
                out.append(None)
                continue
            out.append(np.stack([self._motion_row(m) for m in found]))
        return out
