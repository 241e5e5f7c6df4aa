"""``Trials``: a batch of one-channel trials on one time grid, the data every per-motion
fit, posterior and benchmark reads."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import equinox as eqx
import numpy as np

from frictionfit.errors import FitError
from frictionfit.fit._guess import direction_of
from frictionfit.fit.result import FitResult
from frictionfit.recording import check_newtons

__all__ = ["Trials", "as_trials"]


class Trials(eqx.Module):
    """Trials of one force channel each, sharing a uniform time grid; built once.

    Attributes
    ----------
    t : ndarray (n_samples,)
        Sample times, s.
    y : ndarray (n_trials, n_samples)
        Force, N (float64; NaN where a sample is missing).
    drive_input : tuple of ndarray (n_trials,), or ndarray (n_trials, n_samples)
        ``(t_out, t_back)`` command times, s (``drive == "events"``); or the
        displacement, mm (``drive == "given"``).
    direction : ndarray (n_trials,)
        +1/-1, the sign with which each channel sees the force.
    mask : ndarray (n_trials, n_samples) of bool
        The usable samples (:meth:`FitResult.sample_mask`): finite, and not in a run at a
        clipping extreme. Every fit and posterior of these trials uses exactly these.
    ids : tuple of str
        A name per trial (e.g. ``"<recording>/motion3/thumb_x"``), or empty.
    drive : {"events", "given"}
        What ``drive_input`` holds.

    Examples
    --------
    >>> from frictionfit.simulation.trials import simulate_trials
    >>> ts = simulate_trials("stick_slip", 2, seed=0)
    >>> trials = Trials.from_arrays(ts.y, ts.t, (ts.t_out, ts.t_back))
    >>> trials.n_trials, trials.mask.all()
    (2, True)
    """

    t: np.ndarray
    y: np.ndarray
    drive_input: tuple | np.ndarray
    direction: np.ndarray
    mask: np.ndarray
    ids: tuple[str, ...] = eqx.field(static=True, default=())
    drive: str = eqx.field(static=True, default="events")

    @classmethod
    def from_arrays(cls, y, t, drive_input, *, drive: str = "events", direction=None,
                    ids: Sequence[str] = ()) -> Trials:
        """Trials from arrays as :func:`~frictionfit.fit.fit_trials` takes them.

        ``y`` (n_trials, n_samples), N; ``t`` (n_samples,), s; ``drive_input``
        ``(t_out, t_back)`` (s, scalars or per trial) or a displacement (mm) per sample;
        ``direction`` (+1/-1 per trial) estimated from the out stroke when omitted.
        """
        y = np.atleast_2d(np.asarray(y, dtype=np.float64))
        t = np.asarray(t, dtype=np.float64)
        n = y.shape[0]
        if y.shape[1] != t.size:
            raise FitError(f"y has {y.shape[1]} samples per trial but t has {t.size}")
        if drive not in ("events", "given"):
            raise FitError(f"drive must be 'events' or 'given', not {drive!r}")
        if drive == "events":
            drive_input = tuple(np.broadcast_to(np.asarray(a, np.float64), (n,)).copy()
                                for a in drive_input)
        else:
            drive_input = np.asarray(drive_input, dtype=np.float64).reshape(n, t.size)
        ids = tuple(str(i) for i in ids)
        if ids and len(ids) != n:
            raise FitError(f"{len(ids)} ids for {n} trials")
        trials = cls(t, y, drive_input, np.zeros(n), FitResult.sample_mask(y), ids, drive)
        if direction is None:
            direction = direction_of(t, y, *trials.guess_times)
        return replace(trials, direction=np.broadcast_to(
            np.asarray(direction, dtype=np.float64), (n,)).copy())

    @classmethod
    def from_motions(cls, motions: Sequence, channels: Sequence[str] | None = None,
                     direction=None) -> Trials:
        """Each of ``channels`` (default: all) of every motion
        (:class:`~frictionfit.segmentation.Motion`) as a trial, motion by motion, on the time
        grid of the first motion: a longer motion is cut, a shorter one padded with NaN.
        Ids are ``"<recording>/motion<index>/<channel>"``."""
        if not motions:
            raise FitError("no motions to make trials of")
        t = np.asarray(motions[0].t, dtype=np.float64)
        ys, t_out, t_back, ids = [], [], [], []
        for m in motions:
            n = min(t.size, m.t.size)
            names = [ch.name for ch in m.channels]
            for name in names if channels is None else channels:
                if name not in names:
                    raise FitError(f"motion {m.index} of {m.recording} has no channel "
                                   f"{name!r}; channels are {names}")
                check_newtons(m.recording, m.channels, [name])
                y = np.full(t.size, np.nan)
                y[:n] = m.samples[:n, names.index(name)]
                ys.append(y)
                t_out.append(m.t_out)
                t_back.append(m.t_back)
                ids.append(f"{m.recording}/motion{m.index}/{name}")
        return cls.from_arrays(np.asarray(ys), t, (np.asarray(t_out), np.asarray(t_back)),
                               direction=direction, ids=ids)

    @property
    def n_trials(self) -> int:
        return int(self.y.shape[0])

    @property
    def dt(self) -> float:
        """The sample interval, s (1 for a single sample); FitError unless uniform."""
        t = self.t
        dt = float(t[1] - t[0]) if t.size > 1 else 1.0
        if t.size > 2 and not np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-12):
            raise FitError("t must be uniformly sampled (re-grid missing samples as NaN)")
        return dt

    @property
    def filled(self) -> np.ndarray:
        """``y`` with 0 where a sample is not used, N."""
        return np.where(self.mask, self.y, 0.0)

    @property
    def guess_times(self) -> tuple[np.ndarray, np.ndarray]:
        """Per trial, the out and back command times the starting guesses use, s (for a
        given displacement, the grid's start and a second past its end)."""
        if self.drive == "events":
            return self.drive_input
        n = self.n_trials
        return np.full(n, self.t[0]), np.full(n, self.t[-1] + 1.0)

    @property
    def groups(self) -> list[str]:
        """Per trial, its id without the last part (the channel): the motion it belongs to."""
        return [i.rsplit("/", 1)[0] for i in self.ids]

    def take(self, rows) -> Trials:
        """The trials ``rows`` (indices, a mask or a slice), in that order."""
        idx = np.arange(self.n_trials)[rows]
        drive_input = (tuple(a[idx] for a in self.drive_input) if self.drive == "events"
                       else self.drive_input[idx])
        return replace(self, y=self.y[idx], drive_input=drive_input,
                       direction=self.direction[idx], mask=self.mask[idx],
                       ids=tuple(self.ids[i] for i in idx) if self.ids else ())

    def arrays_only(self) -> Trials:
        """The same trials without ids: a pytree of arrays alone, whose shape (not its
        names) decides when a jitted function recompiles."""
        return replace(self, ids=())


def as_trials(y, t=None, drive_input=None, *, drive: str = "events", direction=None) -> Trials:
    """``y`` itself when it is :class:`Trials` (which bring their own ``t``, ``drive_input``
    and ``direction``), else :meth:`Trials.from_arrays` of the arrays."""
    if not isinstance(y, Trials):
        return Trials.from_arrays(y, t, drive_input, drive=drive, direction=direction)
    given = [name for name, v in (("t", t), ("drive_input", drive_input),
                                  ("direction", direction)) if v is not None]
    if given:
        raise FitError(f"Trials bring their own {', '.join(given)}: do not pass them again")
    return y
