"""Shared plumbing of the rubbing feature sets: channels, motions, NaN filling, aggregation."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from frictionfit.errors import RecordingError
from frictionfit.recording import Recording, kept_per_recording
from frictionfit.segmentation import Motion, segment

#: The four in-plane force channels of the rubbing rig (OptoForce sensors), N.
RUBBING_CHANNELS = ("thumb_x", "thumb_y", "index_x", "index_y")
PHASES = ("out", "back")


@kept_per_recording
def _segmented(rec: Recording, filter_n: int | None) -> list[Motion]:
    """``segment(rec, filter_n=filter_n)``, kept per recording: every feature set of a
    pipeline gets the same list of motions."""
    return segment(rec, filter_n=filter_n)


def motions(rec: Recording, channels: Sequence[str], filter_n: int | None = None) -> list[Motion]:
    """The non-preparatory motions of ``rec``; raises RecordingError naming what is missing."""
    missing = [c for c in channels if c not in rec.channel_names]
    if missing:
        raise RecordingError(f"no channel {missing[0]!r}; channels are {list(rec.channel_names)}",
                             path=rec.name, channel=missing[0])
    found = list(_segmented(rec, filter_n))
    if not found:
        raise RecordingError("no complete motion after the preparatory one", path=rec.name)
    return found


def channel_samples(motion: Motion, channels: Sequence[str]) -> np.ndarray:
    """Samples of ``channels`` (in that order) of one motion, (n_samples, n_channels), N."""
    names = [c.name for c in motion.channels]
    return motion.samples[:, [names.index(c) for c in channels]]


def command_times(motion: Motion) -> dict[str, float]:
    """Seconds from motion start of the ``out`` and ``back`` movement commands."""
    return {"out": motion.t_out, "back": motion.t_back}


def fill_gaps(x: np.ndarray) -> np.ndarray:
    """Linear interpolation over NaN along axis 0 (edges held); all-NaN columns stay NaN."""
    x = np.array(x, dtype=np.float64)
    idx = np.arange(x.shape[0])
    for col in x.reshape(x.shape[0], -1).T if x.ndim > 1 else [x]:
        ok = np.isfinite(col)
        if ok.any() and not ok.all():
            col[~ok] = np.interp(idx[~ok], idx[ok], col[ok])
    return x
