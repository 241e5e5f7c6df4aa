"""One channel of a rubbing recording as a whole fit takes it: :class:`MeasurementData`.

:func:`measurement_data` puts the channel on its time grid (dropped rows, NaN, spikes,
stuck values and clipped or overloaded runs masked) as block means: single samples while
the finger moves, blocks of 10 while it holds; the ``move`` events give the commands and
their directions, the holds and peaks the data's starting values, and the motor's position
reads, where the recording has them, each movement's timing.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from frictionfit.fit._guess import saturated_samples
from frictionfit.fit._problem import noise_scale
from frictionfit.fit.motor import MotorTiming, motor_timing
from frictionfit.recording import DEAD_CHANNEL_SPAN, Recording, check_newtons
from frictionfit.segmentation import checked_grid, moving_average

__all__ = ["FINE_S", "MeasurementData", "measurement_data"]


#: Seconds after each ``move`` command sampled finely (``decimate``): motor delay, the
#: movement and the fast start of the relaxation. The rest is averaged over ``coarse``.
FINE_S = 0.3


@dataclass(frozen=True)
class MeasurementData:
    """One channel of one recording, ready to fit.

    ``y`` (N): block means at times ``t`` (s, increasing, not uniform); ``weight``: the
    square root of each block's sample count (0: not fitted); ``noise``: the sd (N) of one
    sample; ``commands`` (s) and ``signs`` (+1 out, -1 back) of the ``move`` events;
    ``guess`` the data-driven starting values (physical units), ``direction`` (+1/-1),
    the recording's ``session`` within its rig (``Recording.session``; ``None``: none) and
    ``stretch``: each movement's duration over the rig's ``ramp`` (``None``: 1 for all, stored
    as ones);
    ``motor``: the movements as the motor reported them
    (:func:`~frictionfit.fit.motor.motor_timing`; ``None`` when the recording has no
    position reads), which then set ``commands``, ``stretch`` and the rig's starting values;
    ``clipped``: how many samples sat in a run at the channel's extreme (a saturated sensor)
    or were flagged overloaded by the DAQ: left out, and the fit's status says so;
    ``stroke_mm``: the rig's nominal stroke the recording declares (mm, ``None``: not
    declared), a fact about the rig that the fit does not use (its travel is in the model's
    ``stroke_mm``, one nominal unit per movement): ``k`` per mm is ``k * model stroke /
    stroke_mm``.
    """

    name: str
    channel: str
    t: np.ndarray
    y: np.ndarray
    weight: np.ndarray
    noise: float
    commands: np.ndarray
    signs: np.ndarray
    direction: float
    guess: dict
    session: object = None
    stretch: np.ndarray | None = None
    motor: MotorTiming | None = None
    clipped: int = 0
    stroke_mm: float | None = None

    def __post_init__(self):
        if self.stretch is None:  # frozen: set once, so every reader sees an array
            object.__setattr__(self, "stretch", np.ones_like(self.commands, dtype=np.float64))

    @property
    def mask(self) -> np.ndarray:
        """The blocks the fit uses."""
        return self.weight > 0

    @property
    def drive(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(commands, signs, stretch)``: what moves the finger (the model's drive data)."""
        return self.commands, self.signs, self.stretch

    def driven_by(self, drive: tuple) -> MeasurementData:
        """This item with another drive ``(commands, signs, stretch)`` (each movement's
        timing; the signs are kept)."""
        commands, _, stretch = (np.asarray(a) for a in drive)
        return replace(self, commands=commands, stretch=stretch)

    def halved(self) -> MeasurementData:
        """This item with neighbouring blocks merged in pairs (weighted means; for a first
        fit, which a second fit on the item itself polishes)."""
        m = self.y.size // 2 * 2
        w2 = (self.weight[:m] ** 2).reshape(-1, 2)
        total = w2.sum(axis=1)

        def merged(a):
            pairs = a[:m].reshape(-1, 2)
            plain = pairs.mean(axis=1)  # where both blocks are unused
            return np.where(total > 0, (w2 * pairs).sum(axis=1) / np.maximum(total, 1e-300),
                            plain)

        return replace(self, t=merged(self.t), y=merged(self.y), weight=np.sqrt(total))


def _move_signs(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """Times (s) of the ``move`` events and their signs: the first target is out (+1);
    moves without targets alternate out and back, as the protocol does."""
    moves = [e for e in rec.events if e.kind == "move"]
    if not moves:
        raise ValueError(f"{rec.name}: no 'move' events; a measurement fit needs the commands")
    out = moves[0].target
    signs = (np.array([1.0 if e.target == out else -1.0 for e in moves])
             if all(e.target is not None for e in moves)
             else np.where(np.arange(len(moves)) % 2 == 0, 1.0, -1.0))
    return np.array([e.t for e in moves]), signs


def _block_edges(t: np.ndarray, commands: np.ndarray, fine: int, coarse: int) -> np.ndarray:
    """Sample indices where blocks start (and the end): ``fine`` samples per block within
    ``FINE_S`` after a command, ``coarse`` elsewhere; no block straddles a zone boundary."""
    in_fine = np.zeros(t.size, dtype=bool)
    for c in commands:
        in_fine |= (t >= c) & (t < c + FINE_S)
    bounds = np.flatnonzero(np.diff(in_fine.astype(np.int8))) + 1
    edges = []
    for lo, hi in zip(np.r_[0, bounds], np.r_[bounds, t.size], strict=True):
        edges.append(np.arange(lo, hi, fine if in_fine[lo] else coarse))
    return np.r_[np.concatenate(edges), t.size]


def _block_means(t, y, ok, edges) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per block: mean time and value of its usable samples, and their count (a block with
    fewer than half its samples usable counts 0)."""
    idx = np.repeat(np.arange(edges.size - 1), np.diff(edges))
    count = np.bincount(idx, weights=ok, minlength=edges.size - 1)
    size = np.diff(edges)
    t_mean = np.bincount(idx, weights=np.where(ok, t, 0.0)) / np.maximum(count, 1)
    t_mean = np.where(count > 0, t_mean, np.bincount(idx, weights=t) / size)
    y_mean = np.bincount(idx, weights=np.where(ok, y, 0.0)) / np.maximum(count, 1)
    return t_mean, y_mean, np.where(count * 2 >= size, count, 0.0)


def _guess(t, y, ok, commands, signs, stroke_mm: float) -> tuple[float, dict]:
    """Direction and starting values from the holds and peaks of the strokes (``t``
    uniform, ``y`` with NaN where not usable)."""
    smooth = moving_average(np.where(ok, y, np.nan), 9)
    holds = {+1.0: [], -1.0: []}
    peaks, slopes = [], []
    for c, s in zip(commands, signs, strict=True):
        hold = (t > c + 0.5) & (t < c + 0.95)
        if np.isfinite(smooth[hold]).any():
            holds[s].append(np.nanmedian(smooth[hold]))
    lo = np.median(holds[-1.0]) if holds[-1.0] else np.nanmedian(smooth)
    hi = np.median(holds[+1.0]) if holds[+1.0] else np.nanmedian(smooth)
    direction = 1.0 if hi >= lo else -1.0
    mid, hold = 0.5 * (hi + lo), 0.5 * abs(hi - lo)
    for c, s in zip(commands, signs, strict=True):
        win = (t > c) & (t < c + 0.4)
        dev = direction * s * (smooth[win] - mid)
        if np.isfinite(dev).any():
            peaks.append(np.nanmax(dev))
            slopes.append(np.nanmax(np.gradient(dev) / (t[1] - t[0])))
    peak = max(float(np.median(peaks)) if peaks else 1.0, 1e-3)
    slope = float(np.median(slopes)) if slopes else 10.0
    ramp = 0.125
    guess = {"offset": mid, "k": max(slope * ramp / stroke_mm, 1e-2),
             "f_kin": 0.8 * peak, "f_static_excess": 0.2 * peak,
             "relax_frac": float(np.clip(1.0 - hold / peak, 0.05, 0.8)), "tau": 0.15,
             "relax_frac2": 0.1, "tau2": 1.0, "ramp": ramp, "delay": 0.025}
    return direction, guess


def measurement_data(rec: Recording, channel: str, *, decimate: int = 1, coarse: int = 10,
                     skip_motions: int = 1, stroke_mm: float = 1.0) -> MeasurementData:
    """One channel of ``rec``, faults masked (dropped rows, NaN, spikes, stuck values, runs
    clipped at an extreme or flagged overloaded by the DAQ), as
    block means: ``decimate`` samples per block while the finger moves, ``coarse`` while it
    holds; the blocks before the out command of motion ``skip_motions`` are not fitted.
    ValueError, naming the recording and channel, for a channel absent, not in N or without
    signal."""
    if channel not in rec.channel_names:
        raise ValueError(f"{rec.name}: no channel {channel!r}; channels are "
                         f"{list(rec.channel_names)}")
    check_newtons(rec.name, rec.channels, [channel])
    commands, signs = _move_signs(rec)
    t_grid, grid, spike, stuck = checked_grid(rec)
    j = rec.channel_names.index(channel)
    clipped = saturated_samples(grid[None, :, j])[0] | rec.overloaded(channel, t_grid)
    ok = np.isfinite(grid[:, j]) & ~spike[:, j] & ~stuck & ~clipped
    if not ok.any() or np.ptp(grid[ok, j]) <= DEAD_CHANNEL_SPAN:
        raise ValueError(f"{rec.name}: channel {channel!r} " + (
            f"is constant at {grid[ok, j][0]:.6g} {rec.channels[j].unit} (a dead sensor?): "
            "no force to fit" if ok.any() else "has no usable sample"))
    y = np.where(ok, grid[:, j], 0.0)
    direction, guess = _guess(t_grid, np.where(ok, y, np.nan), ok, commands, signs, stroke_mm)
    first = 2 * skip_motions
    start = commands[first] if first < commands.size else np.inf
    # the motions not fitted only carry the contact's state: coarse blocks throughout
    t, y_mean, count = _block_means(t_grid, y, ok,
                                    _block_edges(t_grid, commands[first:], decimate, coarse))
    noise = float(noise_scale(np.where(ok, y, np.nan)[None], ok[None])[0])
    data = MeasurementData(rec.name, channel, t, y_mean, np.sqrt(count) * (t >= start), noise,
                           commands, signs, direction, guess, rec.session,
                           clipped=int(clipped.sum()), stroke_mm=rec.stroke_mm)
    motor = motor_timing(rec, commands, signs)
    return data if motor is None else _driven_by_motor(data, motor)


def _driven_by_motor(d: MeasurementData, motor: MotorTiming) -> MeasurementData:
    """``d`` with each movement's onset and duration from the motor's reads, around the
    median latency and duration (the rig's ``delay`` and ``ramp``; movements the reads
    miss keep the median)."""
    seen = motor.seen
    if not seen.any():
        return d
    latency = float(np.median((motor.onset - d.commands)[seen]))
    ramp = float(np.median(motor.duration[seen]))
    return replace(d, commands=np.where(seen, motor.onset - latency, d.commands),
                   stretch=np.where(seen, motor.duration / ramp, 1.0), motor=motor,
                   guess=d.guess | {"delay": latency, "ramp": ramp, "accel": motor.accel})
