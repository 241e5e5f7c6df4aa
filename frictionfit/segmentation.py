"""Motions and phases of a rubbing measurement: from ``move`` events, or from the force alone.

A measurement is a series of motions; each starts ``pre_s`` before its ``move p2``
command and ends ``pre_s`` before the next one. Samples are put back on the
uniform ``1/sample_rate`` grid, with NaN where the data link dropped them, so
fits see missing data as missing.

Phase boundaries (movement start and stop) are found in the force. All channels
are combined into one signal (their first principal component, after spikes are
removed), and each boundary is placed by a least-squares change-point fit on a
0.25-ms grid:

- a movement *start* is where the signal leaves a linear baseline with a
  polynomial onset ``c1 (t - t0)+ + c2 (t - t0)+^2 + c3 (t - t0)+^3``;
- a movement *stop* is where the drop that the finger's deceleration causes in
  the sliding force ends: a linear ramp of width ``w`` ending at ``t0`` on a
  quadratic background.

With events, each search starts at the command; without events (or with
``use_events=False``), movements are found by change detection: bursts of fast
force change, alternating in sign between out and back strokes, and the command
time is taken as ``lag_s`` before the detected start.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.ndimage import maximum_filter1d, median_filter

from frictionfit.errors import RecordingError
from frictionfit.recording import GRID_LIMIT, Channel, Recording, kept_per_recording

__all__ = ["Motion", "Movement", "Phase", "detect_movements", "moving_average", "regrid",
           "robust_sd", "segment", "suspect_samples"]

_GRID_S = 0.25e-3  # resolution of the change-point grids, s
#: Exact repeats of a whole row (every channel) this long are a stuck data link.
STUCK_MIN = 15


@dataclass(frozen=True)
class Phase:
    """``kind``: move_out, relax_out, move_back or relax_back; times in s from motion start."""

    kind: str
    start_s: float
    stop_s: float


@dataclass(frozen=True)
class Movement:
    """One finger movement: ``target`` ``"p2"`` (out) or ``"p1"`` (back), start/stop in s.

    ``command`` is the ``move`` command time (s), or None where it was not in the events;
    ``detected`` is False where the force did not show the boundaries and nominal
    times (command + lag, + nominal duration) stand in.
    """

    target: str
    start: float
    stop: float
    command: float | None = None
    detected: bool = True


@dataclass(frozen=True, eq=False)
class Motion:
    """One rubbing motion: uniform-grid samples (NaN where missing) and its command times (s).

    ``t0`` is the recording time (s) of the motion's first sample, so a phase boundary
    ``b`` (s from motion start) is at ``t0 + b`` in the recording. ``movements`` are the
    out and back :class:`Movement`; ``problems`` name what was masked (missing samples,
    spikes, stuck values, samples the DAQ flagged overloaded) or guessed (boundaries the
    force did not show).
    """

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
    t0: float = 0.0
    movements: tuple[Movement, ...] = field(default=())
    problems: tuple[str, ...] = ()


#: The median absolute deviation of a normal sample over its sd (``scipy.special.ndtri(0.75)``).
_MAD_PER_SD = 0.6744897501960817


def robust_sd(x: np.ndarray, axis: int | None = None, centre: float | None = None):
    """The sd of a normal sample from its median absolute deviation about its median (or
    about ``centre``), along ``axis``: ``scipy.stats.median_abs_deviation(x, axis,
    scale="normal")`` to the bit, without importing ``scipy.stats`` (0.7 s of every process
    that fits)."""
    x = np.asarray(x)
    mid = np.median(x, axis=axis, keepdims=True) if centre is None else centre
    return np.median(np.abs(x - mid), axis=axis) / _MAD_PER_SD


def moving_average(x: np.ndarray, n: int = 9) -> np.ndarray:
    """Centred moving average over ``n`` samples along axis 0, ignoring NaN; same length
    (a signal shorter than ``n`` is averaged over its own length)."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape[0] == 0:
        return x.copy()
    finite = np.isfinite(x)
    kernel = np.ones(min(n, x.shape[0]))
    flat = x.reshape(x.shape[0], -1)
    ok = finite.reshape(flat.shape)
    out = np.empty_like(flat)
    for j in range(flat.shape[1]):
        total = np.convolve(np.where(ok[:, j], flat[:, j], 0.0), kernel, mode="same")
        count = np.convolve(ok[:, j].astype(np.float64), kernel, mode="same")
        out[:, j] = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return out.reshape(x.shape)


def regrid(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """Samples on the uniform grid ``t[0] + k / sample_rate_hz``; NaN rows for dropped samples.

    RecordingError for fewer than two samples, time stamps not finite and increasing, or a
    grid over :data:`~frictionfit.recording.GRID_LIMIT` times the rows (more missing samples
    than the file holds): memory is bounded by what the file holds, never by what its time
    stamps claim."""
    if rec.n_samples < 2 or not np.all(np.isfinite(rec.t)) or np.any(np.diff(rec.t) <= 0):
        why = (f"only {rec.n_samples} sample(s)" if rec.n_samples < 2
               else "its time stamps are not finite and increasing")
        raise RecordingError(f"no uniform grid: {why}", path=rec.name)
    if (rec.t[-1] - rec.t[0]) * rec.sample_rate_hz + 1 > GRID_LIMIT * rec.n_samples:
        raise RecordingError(f"its time stamps span {rec.t[-1] - rec.t[0]:.6g} s for "
                             f"{rec.n_samples} rows at {rec.sample_rate_hz:g} Hz: more missing "
                             "samples than the recording holds (a corrupted time stamp?)",
                             path=rec.name)
    k = rec.grid_slots
    n = int(k[-1]) + 1 if k.size else 0
    grid = np.full((n, rec.samples.shape[1]), np.nan)
    grid[k] = rec.samples
    return rec.t[0] + np.arange(n) / rec.sample_rate_hz, grid


def suspect_samples(grid: np.ndarray, *, stuck_min: int = STUCK_MIN
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Transmission faults the file format cannot show: spikes and stuck values.

    Parameters
    ----------
    grid : ndarray (n_samples, n_channels)
        Uniform-grid samples (NaN where missing).
    stuck_min : int
        Rows repeated exactly (every channel) at least this many times are stuck.

    Returns
    -------
    spike : ndarray of bool (n_samples, n_channels)
        Samples further from a 7-sample running median than ``12 sd``, 50 mN and 4 times
        the local sample-to-sample change.
    stuck : ndarray of bool (n_samples,)
        Repeats of a row after its first occurrence, in runs of ``stuck_min`` or more
        (none where most rows repeat: noise-free data).
    """
    x = np.array(grid, dtype=np.float64)
    ok = np.isfinite(x)
    idx = np.arange(x.shape[0])
    spike = np.zeros(x.shape, dtype=bool)
    for j in range(x.shape[1]):
        if ok[:, j].sum() < 2:
            continue
        for _ in range(3):  # spikes close together hide each other: peel them off
            good = ok[:, j] & ~spike[:, j]
            smooth = np.interp(idx, idx[good], x[good, j])  # spikes found so far bridged
            resid = np.where(ok[:, j], x[:, j], smooth) - median_filter(smooth, 7, mode="nearest")
            spread = robust_sd(resid)
            # a sharp static peak is no spike: compare with the local sample-to-sample change
            slope = median_filter(np.abs(np.diff(smooth, prepend=smooth[0])), 7, mode="nearest")
            new = ok[:, j] & (np.abs(resid) > np.maximum(max(12 * spread, 0.05), 4 * slope))
            if not (new & ~spike[:, j]).any():
                break
            spike[:, j] |= new
    same = np.r_[False, np.all(np.diff(x, axis=0) == 0, axis=1)]
    if same.mean() > 0.5:  # rows mostly repeat: noise-free (synthetic) data, nothing is stuck
        same[:] = False
    edges = np.flatnonzero(np.diff(np.r_[0, same.astype(np.int8), 0]))
    stuck = np.zeros(x.shape[0], dtype=bool)
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if b - a >= stuck_min - 1:
            stuck[a:b] = True
    return spike, stuck


class CheckedGrid(NamedTuple):
    """A recording on its uniform grid (:func:`regrid`: ``t`` in s, ``samples`` NaN where
    dropped) and the faults :func:`suspect_samples` finds there (``spike``, ``stuck``:
    read-only, shared by everything that reads the recording)."""

    t: np.ndarray
    samples: np.ndarray
    spike: np.ndarray
    stuck: np.ndarray


def checked_grid(rec: Recording) -> CheckedGrid:
    """``rec`` on its uniform grid with its faults; the faults are looked for once per
    recording (the segmentation and every channel's fit ask for the same ones)."""
    return CheckedGrid(*regrid(rec), *_faults(rec))


@kept_per_recording
def _faults(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """:func:`suspect_samples` on ``rec``'s grid, read-only."""
    faults = suspect_samples(regrid(rec)[1])
    for a in faults:
        a.setflags(write=False)
    return faults


def _combined(checked: CheckedGrid) -> tuple[np.ndarray, np.ndarray]:
    """One signal from all channels (first principal component, N) and its validity mask.

    Missing samples, spikes and stuck values are masked, then bridged linearly so the
    filters and the component see no holes.
    """
    grid, spike, stuck = checked.samples, checked.spike, checked.stuck
    x = np.array(grid, dtype=np.float64)
    ok = np.isfinite(x) & ~spike & ~stuck[:, None]
    idx = np.arange(x.shape[0])
    for j in range(x.shape[1]):
        if ok[:, j].sum() < 2:
            x[:, j], ok[:, j] = 0.0, False
            continue
        x[:, j] = np.interp(idx, idx[ok[:, j]], x[ok[:, j], j])
    centred = x - np.median(x, axis=0)
    _, _, vt = np.linalg.svd(centred[:: max(1, x.shape[0] // 4000)], full_matrices=False)
    return centred @ vt[0], ok.all(axis=1)


def _best(y: np.ndarray, w: np.ndarray, common: np.ndarray, varying: np.ndarray) -> int:
    """Index ``g`` of the design ``[common, varying[g]]`` (columns ``(n, q)`` and ``(G, n,
    m)``) whose weighted least-squares fit of ``y`` leaves the least RSS: the common
    columns are projected out once, so each candidate costs an ``m x m`` solve."""
    sw = np.sqrt(w)
    q, _ = np.linalg.qr(common * sw[:, None])
    y_perp = y * sw - q @ (q.T @ (y * sw))
    c = varying * sw[None, :, None]
    c_perp = c - q @ (q.T @ c)
    gram = np.swapaxes(c_perp, 1, 2) @ c_perp + 1e-12 * np.eye(varying.shape[2])
    b = np.swapaxes(c_perp, 1, 2) @ y_perp  # (G, m)
    explained = np.sum(b * np.linalg.solve(gram, b[..., None])[..., 0], axis=1)
    return int(np.argmax(explained))


def _refine_start(s: np.ndarray, ok: np.ndarray, rate: float, lo: int, hi: int) -> float | None:
    """Movement start (samples, fractional) in ``[lo, hi]``: baseline then polynomial onset."""
    lo, hi = max(lo, 0), min(hi, s.size - 1)
    if hi - lo < 30:
        return None
    base = np.median(s[max(lo - 20, 0):lo + 5])
    dev = s[lo:hi] - base
    swing = dev[np.argmax(np.abs(dev))]
    over = np.flatnonzero(np.sign(swing) * dev > 0.2 * abs(swing))
    if not over.size or abs(swing) < 1e-9:
        return None
    c = lo + int(over[0])
    win = np.arange(c - int(0.06 * rate), c + 1)
    win = win[win >= 0]
    tt = (win - win[0]) / rate
    t0s = np.arange(max(win[0] + 5, c - int(0.04 * rate)), c, _GRID_S * rate)
    h = np.clip(tt[None, :] - (t0s[:, None] - win[0]) / rate, 0.0, None)
    common = np.stack([np.ones_like(tt), tt], axis=1)
    return float(t0s[_best(s[win], ok[win].astype(float), common,
                           np.stack([h, h**2, h**3], axis=-1))])


def _refine_stop(s: np.ndarray, ok: np.ndarray, rate: float, start: float, sign: float,
                 span: tuple[float, float], noise: float, last: bool = True) -> float | None:
    """Movement stop (samples): end of the deceleration drop, searched ``span`` s after start.

    A drop is a candidate where the signal runs against the loading direction
    (``sign``) over 6-18 ms and is flat-ish in the 12 ms before and after. ``last``: take
    the latest candidate above ``10 noise`` (the deceleration ends the movement; an
    earlier one is the slip-weakening drop after the static peak); else the strongest.
    """
    a, b = int(start + span[0] * rate), min(int(start + span[1] * rate), s.size - int(0.03 * rate))
    if b - a < 10:
        return None
    k = int(0.012 * rate)
    idx = np.arange(a, b)
    after = np.abs(s[idx + k] - s[idx])
    score = np.full(idx.size, -np.inf)
    for w in (0.006, 0.01, 0.014, 0.018):  # the deceleration lasts as long as the acceleration
        n = int(w * rate)
        drop = -sign * (s[idx] - s[idx - n])  # against the direction of the rise
        ahead = np.abs(s[idx - n] - s[np.maximum(idx - n - k, 0)])  # sliding: flat before
        score = np.maximum(score, drop - ahead - after)
    peaks = np.flatnonzero((score >= max(0.05 * score.max(), 10 * noise))
                           & (score == maximum_filter1d(score, 2 * k + 1, mode="nearest")))
    c = int(idx[peaks[-1]]) if last and peaks.size else int(idx[np.argmax(score)])
    win = np.arange(c - int(0.03 * rate), c + int(0.025 * rate))
    tt = (win - win[0]) / rate
    t0s = np.arange(max(c - int(0.01 * rate), a), min(c + int(0.01 * rate), b), _GRID_S * rate)
    widths = np.arange(0.004, 0.022, 0.002)
    t0v, wv = (a.ravel() for a in np.meshgrid(t0s, widths, indexing="ij"))
    ramp = np.clip(((t0v[:, None] - win[0]) / rate - tt[None, :]) / wv[:, None], 0.0, 1.0)
    common = np.stack([np.ones_like(tt), tt, tt**2], axis=1)
    return float(t0v[_best(s[win], ok[win].astype(float), common, ramp[..., None])])


def _stops(s: np.ndarray, ok: np.ndarray, rate: float, starts: list[float | None],
           tolerance_s: float = 0.008) -> list[float | None]:
    """Stops of all movements; durations far from the recording's median are searched again.

    The motor's movement time hardly changes within a measurement, so a stop more than
    ``tolerance_s`` from ``start + median duration`` is looked for again within
    ``tolerance_s`` of it.
    """
    signs = [None if a is None else
             float(np.sign(s[min(int(a) + int(0.05 * rate), s.size - 1)] - s[int(a)]))
             for a in starts]
    # robust sd of the departures from the local mean (about zero, not their median)
    noise = float(robust_sd(s - moving_average(s, 15), centre=0.0))
    stops = [None if a is None else _refine_stop(s, ok, rate, a, g, (0.03, 0.25), noise)
             for a, g in zip(starts, signs, strict=True)]
    durations = [(b - a) / rate for a, b in zip(starts, stops, strict=True)
                 if a is not None and b is not None]
    if len(durations) < 3:
        return stops
    med = float(np.median(durations))
    for i, (a, b) in enumerate(zip(starts, stops, strict=True)):
        if a is not None and (b is None or abs((b - a) / rate - med) > tolerance_s):
            stops[i] = _refine_stop(s, ok, rate, a, signs[i],
                                    (med - tolerance_s, med + tolerance_s), noise, last=False)
    return stops


def _bursts(s: np.ndarray, rate: float, min_gap_s: float = 0.4) -> list[tuple[int, float]]:
    """Onsets (sample) and signs of bursts of fast change: the loading of each movement."""
    k = int(0.01 * rate)
    smooth = moving_average(s, 9)
    d = np.zeros_like(s)
    d[k:-k] = smooth[2 * k:] - smooth[:-2 * k]
    level = np.quantile(np.abs(d), 0.999)
    hot = np.flatnonzero(np.abs(d) > 0.2 * level) if level > 0 else np.array([], dtype=int)
    out: list[tuple[int, float]] = []
    for i in hot:
        if not out or i - out[-1][0] > min_gap_s * rate:
            out.append((int(i), float(np.sign(d[i]))))
    return out


def detect_movements(
    rec: Recording,
    *,
    use_events: bool = True,
    lag_s: float = 0.025,
    move_s: float = 0.15,
) -> list[Movement]:
    """Find every finger movement's start and stop (s, recording time) in the force.

    Parameters
    ----------
    rec : Recording
        A rubbing measurement (any channels that see the tangential force).
    use_events : bool, default True
        Search after each ``move`` command; False (or no events) finds the movements
        by change detection alone.
    lag_s : float
        Nominal motor latency (s): without events, the command time is taken as the
        detected start minus ``lag_s``; with events, where the force shows nothing,
        the start is taken as command + ``lag_s``.
    move_s : float
        Nominal movement duration (s): the stop where the force does not show it.

    Returns
    -------
    list of Movement
        In time order.
    """
    checked = checked_grid(rec)
    t = checked.t
    rate = rec.sample_rate_hz
    s, ok = _combined(checked)
    cmds = [(e.t, e.target) for e in rec.events if e.kind == "move" and e.target in ("p1", "p2")]
    found: list[tuple[str, float | None, float | None]] = []  # target, command, start (samples)
    if use_events and cmds:
        for t_cmd, target in sorted(cmds):
            i = int(round((t_cmd - t[0]) * rate))
            found.append((target, t_cmd, _refine_start(s, ok, rate, i, i + int(0.2 * rate))))
    else:
        bursts = _bursts(s, rate)
        gap = np.median(np.diff([i for i, _ in bursts])) if len(bursts) > 1 else np.inf
        # the recording starts just before the first out command (the lab protocol)
        first = 0.0 if not bursts else bursts[0][1] if bursts[0][0] < 0.5 * gap else -bursts[0][1]
        for i, sign in bursts:
            start = _refine_start(s, ok, rate, i - int(0.08 * rate), i + int(0.1 * rate))
            found.append(("p2" if sign == first else "p1", None, start))
    stops = _stops(s, ok, rate, [start for _, _, start in found])
    out = []
    for (target, t_cmd, start), stop in zip(found, stops, strict=True):
        detected = start is not None and stop is not None
        if start is None:
            start = (t_cmd + lag_s - t[0]) * rate
        if stop is None:
            stop = start + move_s * rate
        cmd = t_cmd if t_cmd is not None else t[0] + start / rate - lag_s
        out.append(Movement(target, t[0] + start / rate, t[0] + stop / rate, cmd, detected))
    return out


def segment(
    rec: Recording,
    *,
    drop_first: bool = True,
    filter_n: int | None = None,
    pre_s: float = 0.05,
    move_s: float = 0.15,
    use_events: bool = True,
    lag_s: float = 0.025,
    mask_faults: bool = True,
) -> list[Motion]:
    """Split a measurement into motions and each motion into movement and relaxation phases.

    Parameters
    ----------
    rec : Recording
        A measurement, with ``move`` events (targets ``p2`` then ``p1``) or without.
    drop_first : bool, default True
        Drop motion 0, the preparatory one.
    filter_n : int, optional
        Moving-average length (the published pipeline uses 9); boundaries are found
        on the unfiltered data.
    pre_s : float
        Seconds kept before each out command (the baseline).
    move_s : float
        Nominal movement duration (s), used where the force shows no boundary.
    use_events : bool, default True
        Use the ``move`` commands; False segments from the force alone (as when the
        sidecar has no events).
    lag_s : float
        Nominal motor latency (s); see :func:`detect_movements`.
    mask_faults : bool, default True
        Set spikes and stuck values (see :func:`suspect_samples`) and samples the DAQ
        flagged overloaded to NaN, so fits treat them as missing; ``Motion.problems`` says
        what was masked either way.

    Returns
    -------
    list of Motion
        ``phases`` hold the detected boundaries (s from the motion's start, ``t0``);
        ``t_out``/``t_back`` the commands (estimated as start - ``lag_s`` without events).

    Examples
    --------
    >>> from frictionfit.simulation.measurements import simulate_measurements
    >>> rec, = simulate_measurements([(1, "paper-1", 1)], seed=0, pad_to=1)
    >>> [m.index for m in segment(rec)]
    [1, 2, 3, 4]
    """
    has_events = any(e.kind == "move" and e.target == "p2" for e in rec.events)
    moves = detect_movements(rec, use_events=use_events and has_events, lag_s=lag_s,
                             move_s=move_s)
    outs = [m for m in moves if m.target == "p2"]
    if not outs:
        raise RecordingError("no 'move p2' events and no movements found in the force: "
                             "cannot segment", path=rec.name)
    t, grid, faults = _masked_grid(rec, mask_faults, filter_n)
    rate = rec.sample_rate_hz
    cmds = [m.command for m in outs]
    period = float(np.median(np.diff(cmds))) if len(cmds) > 1 else float(t[-1] - cmds[0] + pre_s)
    n = int(round(period * rate))
    motions = []
    for k, out in enumerate(outs):
        # without events, number motions by time (the first out command is at the start)
        i = k if use_events and has_events else int(round((out.command - t[0]) / period))
        start = int(round((out.command - pre_s - t[0]) * rate))
        back = [m for m in moves if m.target == "p1" and out.command < m.command < out.command
                + period]
        if (drop_first and i == 0) or start < 0 or start + n > grid.shape[0] or not back:
            continue  # the preparatory motion, a truncated one, or one without its back stroke
        t0, ret, rows = t[0] + start / rate, back[0], slice(start, start + n)
        motions.append(Motion(
            rec.name, i, np.arange(n) / rate, grid[rows], rec.channels, rate,
            out.command - t0, ret.command - t0, _phases(out, ret, t0, n / rate),
            {**rec.metadata, "motion": i}, t0=t0, movements=(out, ret),
            problems=_problems(faults, rows, (out, ret)),
        ))
    return motions


def _masked_grid(rec: Recording, mask_faults: bool, filter_n: int | None):
    """The uniform grid of ``rec`` (see :func:`regrid`) with spikes, stuck rows and samples the
    DAQ flagged overloaded (:meth:`~frictionfit.recording.Recording.overloaded`) set to NaN
    (``mask_faults``), then filtered (``filter_n``); and the faults found before: missing
    samples, spikes, stuck rows and overloaded samples."""
    t, grid, spike, stuck = checked_grid(rec)
    missing = ~np.isfinite(grid)
    overloaded = np.column_stack([rec.overloaded(ch.name, t) for ch in rec.channels])
    if mask_faults:
        grid[spike | stuck[:, None] | overloaded] = np.nan
    if filter_n:
        grid = moving_average(grid, filter_n)
    return t, grid, (missing, spike, stuck, overloaded)


def _phases(out: Movement, ret: Movement, t0: float, end: float) -> tuple[Phase, ...]:
    """The four phases of a motion from its two movements (s from the motion's start ``t0``,
    the last ending at ``end``)."""
    return (
        Phase("move_out", out.start - t0, out.stop - t0),
        Phase("relax_out", out.stop - t0, ret.start - t0),
        Phase("move_back", ret.start - t0, ret.stop - t0),
        Phase("relax_back", ret.stop - t0, end),
    )


def _problems(faults: tuple, rows: slice, movements: tuple[Movement, ...]) -> tuple[str, ...]:
    """What ``Motion.problems`` lists for the grid rows ``rows``: counts of the faults found by
    :func:`_masked_grid` and of the boundaries the force did not show."""
    missing, spike, stuck, overloaded = faults
    found = {"missing sample(s)": int(missing[rows].any(axis=1).sum()),
             "spike(s) masked": int(spike[rows].sum()),
             "stuck sample(s) masked": int(stuck[rows].sum()),
             "sample(s) the DAQ flagged overloaded masked": int(overloaded[rows].sum()),
             "boundary(ies) not seen in the force, nominal times used":
                 sum(not mv.detected for mv in movements)}
    return tuple(f"{count} {what}" for what, count in found.items() if count)
