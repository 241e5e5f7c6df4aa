"""Motions and phases of a rubbing measurement, from its ``move`` events.

A measurement is a series of motions; each starts ``pre_s`` before its ``move p2``
command and ends ``pre_s`` before the next one. Samples are put back on the
uniform ``1/sample_rate`` grid, with NaN where the data link dropped them, so
fits see missing data as missing. Phase boundaries here come from the command
times plus a nominal movement duration (``move_s``); detecting them from the
force, and change detection when events are absent, are not implemented yet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from frictionfit.errors import RecordingError
from frictionfit.recording import Channel, Recording

__all__ = ["Motion", "Phase", "moving_average", "regrid", "segment"]


@dataclass(frozen=True)
class Phase:
    """``kind``: move_out, relax_out, move_back or relax_back; times in s from motion start."""

    kind: str
    start_s: float
    stop_s: float


@dataclass(frozen=True, eq=False)
class Motion:
    """One rubbing motion: uniform-grid samples (NaN where missing) and its command times (s)."""

    recording: str
    index: int
    t: np.ndarray
    samples: np.ndarray
    channels: tuple[Channel, ...]
    sample_rate_hz: float
    t_out: float
    t_back: float
    phases: tuple[Phase, ...]
    metadata: dict


def moving_average(x: np.ndarray, n: int = 9) -> np.ndarray:
    """Centred moving average over ``n`` samples along axis 0, ignoring NaN; same length."""
    x = np.asarray(x, dtype=np.float64)
    finite = np.isfinite(x)
    kernel = np.ones(n)
    flat = x.reshape(x.shape[0], -1)
    ok = finite.reshape(flat.shape)
    out = np.empty_like(flat)
    for j in range(flat.shape[1]):
        total = np.convolve(np.where(ok[:, j], flat[:, j], 0.0), kernel, mode="same")
        count = np.convolve(ok[:, j].astype(np.float64), kernel, mode="same")
        out[:, j] = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return out.reshape(x.shape)


def regrid(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """Samples on the uniform grid ``t[0] + k / sample_rate_hz``; NaN rows for dropped samples."""
    k = np.round((rec.t - rec.t[0]) * rec.sample_rate_hz).astype(np.int64)
    n = int(k[-1]) + 1 if k.size else 0
    grid = np.full((n, rec.samples.shape[1]), np.nan)
    grid[k] = rec.samples
    return rec.t[0] + np.arange(n) / rec.sample_rate_hz, grid


def segment(
    rec: Recording,
    *,
    drop_first: bool = True,
    filter_n: int | None = None,
    pre_s: float = 0.05,
    move_s: float = 0.15,
) -> list[Motion]:
    """Split a measurement into motions at its ``move p2`` commands.

    Parameters
    ----------
    rec : Recording
        A measurement with ``move`` events (targets ``p2`` then ``p1``).
    drop_first : bool, default True
        Drop motion 0, the preparatory one.
    filter_n : int, optional
        Moving-average length (the published pipeline uses 9).
    pre_s : float
        Seconds kept before each out command (the baseline).
    move_s : float
        Nominal movement duration (s) used for the phase boundaries.
    """
    outs = [e.t for e in rec.events if e.kind == "move" and e.target == "p2"]
    backs = [e.t for e in rec.events if e.kind == "move" and e.target == "p1"]
    if not outs:
        raise RecordingError("no 'move p2' events: cannot segment without motion commands",
                             path=rec.name)
    t, grid = regrid(rec)
    if filter_n:
        grid = moving_average(grid, filter_n)
    period = float(np.median(np.diff(outs))) if len(outs) > 1 else float(t[-1] - outs[0] + pre_s)
    n = int(round(period * rec.sample_rate_hz))
    motions = []
    for i, t_cmd in enumerate(outs):
        if drop_first and i == 0:
            continue
        start = int(round((t_cmd - pre_s - t[0]) * rec.sample_rate_hz))
        back = [b for b in backs if t_cmd < b < t_cmd + period]
        if start < 0 or start + n > grid.shape[0] or not back:
            continue  # a truncated last motion, or one without its back command
        t_out, t_back = pre_s, back[0] - t_cmd + pre_s
        phases = (
            Phase("move_out", t_out, t_out + move_s),
            Phase("relax_out", t_out + move_s, t_back),
            Phase("move_back", t_back, t_back + move_s),
            Phase("relax_back", t_back + move_s, n / rec.sample_rate_hz),
        )
        motions.append(Motion(
            rec.name, i, np.arange(n) / rec.sample_rate_hz, grid[start:start + n],
            rec.channels, rec.sample_rate_hz, t_out, t_back, phases,
            {**rec.metadata, "motion": i},
        ))
    return motions
