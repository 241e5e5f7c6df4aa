"""The interchange format: one recording = ``<name>.csv`` + ``<name>.json``.

The CSV has a first column ``t`` (seconds from the start) and one column per
channel. The JSON sidecar holds ``sample_rate_hz``, ``channels`` (name, unit),
``events`` (time-stamped commands such as ``{"t": 0.5, "kind": "move",
"target": "p2"}``), ``metadata`` (``label``, ``material``, ``session``, ..., and what the
lab knows about its rig: :data:`RIG_KEYS`, read as :attr:`Recording.rig`)
and ``truth`` (generating parameters of simulated data). A recording made with
an actuator may hold ``motor_positions``, the positions the actuator reported at
the times they were read (see :meth:`Recording.motor_positions`). Unknown keys
are kept and written back. Every loader and the recorder produce a :class:`Recording`;
nothing else in frictionfit parses files.
"""

from __future__ import annotations

import functools
import json
import math
import warnings
import weakref
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from frictionfit._types import OnError, PathType, Samples, Times
from frictionfit.errors import DatasetError, RecordingError

__all__ = [
    "Channel",
    "DatasetWarning",
    "Event",
    "Problem",
    "Recording",
    "Rig",
    "check_channel_names",
    "check_newtons",
    "kept_per_recording",
    "read_dataset",
    "read_recording",
    "recording_paths",
    "validate",
    "within_rig",
    "write_recording",
]

KNOWN_UNITS = frozenset({"N", "mN", "kN", "N m", "counts", "mm", "m", "kPa", "Pa", "V", "1", ""})
#: Force units in newtons: frictionfit computes forces in N, and reads them so.
NEWTONS_PER = {"N": 1.0, "mN": 1e-3, "kN": 1e3}
REQUIRED_SIDECAR_FIELDS = ("sample_rate_hz", "channels")
#: Relative deviation of the median sample interval from 1/sample_rate_hz that is flagged.
RATE_TOLERANCE = 0.02
#: Relative deviation of the data's rate (mean interval between neighbours) from
#: ``sample_rate_hz`` that is named as informational (``"rate_off"``).
RATE_NOTE = 0.005
#: A recording's uniform grid (one slot per 1/sample_rate_hz) may be at most this many
#: times its rows: time stamps claiming more missing samples than the file holds are
#: disqualifying (``"time_span"``), and nothing allocates by them.
GRID_LIMIT = 2
#: Largest force (N) a tactile sensor measures; beyond it the unit is wrong.
FORCE_LIMIT_N = 1e4
#: A channel whose finite samples span less than this (in its unit) is called dead.
DEAD_CHANNEL_SPAN = 1e-12
#: Sidecar key of the actuator's measured positions: ``columns`` (name, unit) of each row
#: in ``reads``, one row per read: request and reply times (s) and the position.
MOTOR_POSITIONS = "motor_positions"
MOTOR_COLUMNS = ({"name": "t_request", "unit": "s"}, {"name": "t_reply", "unit": "s"},
                 {"name": "position", "unit": "counts"})
#: ``metadata`` keys of what a lab knows about its rig, all optional: ``rig`` (str, the
#: rig's name: recordings of one name share one rig), ``stroke_mm`` (the finger's nominal
#: travel per movement, mm > 0: stiffness is then reported per mm of fingertip travel, else
#: per stroke), ``grip_force_n`` (the closing force, N > 0) and ``motor_positions_counts``
#: (the motor's named target positions, e.g. ``{"p1": 1800, "p2": 2300}``, in counts).
RIG_KEYS = ("rig", "stroke_mm", "grip_force_n", "motor_positions_counts")


@dataclass(frozen=True)
class Rig:
    """What a recording's sidecar declares about its rig (``None``: not declared).

    ``name`` (``metadata.rig``), ``stroke_mm`` (mm, the nominal fingertip travel of one
    movement), ``grip_force_n`` (N) and ``motor_positions_counts`` (target name ->
    counts); :data:`RIG_KEYS`.
    """

    name: str | None = None
    stroke_mm: float | None = None
    grip_force_n: float | None = None
    motor_positions_counts: dict[str, float] | None = None

    @classmethod
    def from_metadata(cls, metadata: dict[str, Any], path: PathType = "recording") -> Rig:
        """The rig facts in ``metadata``; :class:`~frictionfit.errors.RecordingError` naming
        ``path`` and the key for a value of the wrong kind (a non-positive stroke, ...)."""
        name = metadata.get("rig")
        if name is not None and not isinstance(name, str):
            raise RecordingError(f"metadata.rig must be a name (a string), not {name!r}",
                                 path=path)
        values = {k: _positive(metadata, k, path) for k in ("stroke_mm", "grip_force_n")}
        positions = metadata.get("motor_positions_counts")
        if positions is not None:
            if not isinstance(positions, dict) or not all(
                    _is_number(v) for v in positions.values()):
                raise RecordingError("metadata.motor_positions_counts must map target names "
                                     f"to positions in counts, not {positions!r}", path=path)
            positions = {str(k): float(v) for k, v in positions.items()}
        return cls(name, motor_positions_counts=positions, **values)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _positive(metadata: dict[str, Any], key: str, path: PathType) -> float | None:
    """``metadata[key]`` as a positive float (None when absent); RecordingError else."""
    v = metadata.get(key)
    if v is None:
        return None
    if not _is_number(v) or v <= 0:
        raise RecordingError(f"metadata.{key} must be a positive number, not {v!r}", path=path)
    return float(v)


@dataclass(frozen=True)
class Channel:
    """One signal column: its name and physical unit (e.g. ``"N"``)."""

    name: str
    unit: str


def check_channel_names(names: Sequence[str]) -> None:
    """ValueError unless each name can head a CSV column of its own and be read back:
    non-empty, unique, not ``t`` (the time column), with no comma, quote or line break,
    and no space at either end."""
    seen = set()
    for name in names:
        bad = ("is empty" if not name else "is the time column's" if name == "t" else
               "holds a comma, quote or line break" if set(name) & set(',"\r\n') else
               "starts or ends with a space" if name != name.strip() else
               "appears twice" if name in seen else None)
        if bad is not None:
            raise ValueError(f"channel name {name!r} {bad}: each channel needs a name of its "
                             "own that a CSV header can hold")
        seen.add(name)


@dataclass(frozen=True)
class Event:
    """A time-stamped command, e.g. ``Event(0.05, "move", "p2")``; ``t`` in seconds."""

    t: float
    kind: str
    target: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"t": self.t, "kind": self.kind}
        if self.target is not None:
            out["target"] = self.target
        out.update(self.extra)
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Event:
        rest = {k: v for k, v in d.items() if k not in ("t", "kind", "target")}
        return cls(float(d["t"]), str(d["kind"]), d.get("target"), rest)


@dataclass(frozen=True)
class Problem:
    """A validation finding: ``kind`` (e.g. ``"nonfinite"``), channel or None, and words."""

    kind: str
    detail: str
    channel: str | None = None

    def __str__(self) -> str:
        chan = f"channel {self.channel!r}: " if self.channel else ""
        return f"{chan}{self.detail}"


def within_rig(metadata: Mapping, key: str = "session") -> Any:
    """``metadata[key]`` as a group of one rig: prefixed by ``metadata["rig"]`` and ``/``
    where a rig is named (two rigs' sessions numbered alike are two groups), as given where
    none is; None where ``key`` is absent."""
    value, rig = metadata.get(key), metadata.get("rig")
    return None if value is None else value if rig is None else f"{rig}/{value}"


@dataclass(frozen=True, eq=False)
class Recording:
    """A multichannel time series with units, events and metadata.

    Parameters
    ----------
    t : ndarray of shape (n_samples,)
        Sample times in seconds from the start of the recording.
    samples : ndarray of shape (n_samples, n_channels)
        The signals, float64, in the units of ``channels``.
    sample_rate_hz : float
        Nominal sample rate in Hz.
    channels : tuple of Channel
        Name and unit of each column of ``samples``.
    events : tuple of Event
        Commands with their times (e.g. the motor's ``move`` commands), kept in time
        order.
    metadata : dict
        ``label`` (the class to learn), ``material``, ``layers``, ``session``,
        ``trial``, the rig's facts (:data:`RIG_KEYS`: ``rig``, ``stroke_mm``, ...; read
        as :attr:`rig`) and any other free key/values.
    truth : dict
        Generating parameters, for simulated data only.
    name : str
        The file stem, or any identifier.
    problems : tuple of Problem
        What validation found and the caller chose to keep going with.
    extra : dict
        Unknown top-level sidecar keys, kept and written back.

    Examples
    --------
    >>> import numpy as np
    >>> rec = Recording.from_arrays(np.zeros((3, 1)) + [[0.0], [1.0], [2.0]], 1000.0, ["fx"])
    >>> rec.n_samples, rec.channel_names
    (3, ('fx',))
    """

    t: Times
    samples: Samples
    sample_rate_hz: float
    channels: tuple[Channel, ...]
    events: tuple[Event, ...] = ()
    metadata: dict[str, Any] = field(default_factory=dict)
    truth: dict[str, Any] = field(default_factory=dict)
    name: str = "recording"
    problems: tuple[Problem, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64)
        samples = np.asarray(self.samples, dtype=np.float64)
        if samples.ndim == 1:
            samples = samples[:, None]
        if samples.ndim != 2 or t.shape != (samples.shape[0],):
            raise RecordingError(
                f"samples of shape {samples.shape} do not match t of shape {t.shape}; "
                "expected samples (n_samples, n_channels) and t (n_samples,)",
                path=self.name,
            )
        if len(self.channels) != samples.shape[1]:
            raise RecordingError(
                f"{len(self.channels)} channels named but samples have {samples.shape[1]} columns",
                path=self.name,
            )
        try:
            check_channel_names([c.name for c in self.channels])
        except ValueError as exc:
            raise RecordingError(str(exc), path=self.name) from None
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "samples", samples)
        object.__setattr__(self, "channels", tuple(self.channels))
        # in time order whatever order the sidecar lists them in (a stable sort)
        object.__setattr__(self, "events", tuple(sorted(self.events, key=lambda e: e.t)))
        object.__setattr__(self, "problems", tuple(self.problems))

    @classmethod
    def from_arrays(
        cls,
        samples: Samples,
        sample_rate_hz: float,
        channel_names: Sequence[str],
        *,
        units: str | Sequence[str] = "N",
        t0: float = 0.0,
        **kwargs: Any,
    ) -> Recording:
        """Build a recording sampled uniformly at ``sample_rate_hz`` from ``t0`` seconds."""
        samples = np.asarray(samples, dtype=np.float64)
        unit_list = [units] * len(channel_names) if isinstance(units, str) else list(units)
        t = t0 + np.arange(samples.shape[0]) / float(sample_rate_hz)
        channels = tuple(Channel(n, u) for n, u in zip(channel_names, unit_list, strict=True))
        return cls(t, samples, float(sample_rate_hz), channels, **kwargs)

    @property
    def n_samples(self) -> int:
        return int(self.samples.shape[0])

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.channels)

    @property
    def label(self) -> Any:
        """``metadata["label"]``: the class to learn, or None."""
        return self.metadata.get("label")

    @property
    def rig(self) -> Rig:
        """What the sidecar declares about the rig (:class:`Rig`; :data:`RIG_KEYS`)."""
        return Rig.from_metadata(self.metadata, self.name)

    @property
    def session(self) -> Any:
        """The recording's session (day) within its rig (:func:`within_rig`), or None."""
        return within_rig(self.metadata)

    @property
    def stroke_mm(self) -> float | None:
        """``metadata["stroke_mm"]``: the rig's nominal fingertip travel per movement (mm),
        or None when not declared (stiffness is then per stroke, not per mm)."""
        return self.rig.stroke_mm

    @property
    def grid_slots(self) -> np.ndarray:
        """Each sample's slot ``k`` on the uniform grid ``t[0] + k / sample_rate_hz``."""
        return np.round((self.t - self.t[0]) * self.sample_rate_hz).astype(np.int64)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if self.n_samples else 0.0

    def channel(self, name: str) -> np.ndarray:
        """The samples of one channel by name."""
        try:
            return self.samples[:, self.channel_names.index(name)]
        except ValueError:
            raise RecordingError(
                f"no channel {name!r}; channels are {list(self.channel_names)}", path=self.name
            ) from None

    def overload_runs(self) -> dict[str, list[tuple[float, int]]]:
        """The runs of samples the acquisition saw flagged overloaded (the DAQ's status
        bits), by channel: ``(t of the first, s; how many)`` each; malformed entries of the
        sidecar's ``acquisition.overloads`` are ignored."""
        acq = self.extra.get("acquisition")
        runs = acq.get("overloads") if isinstance(acq, dict) else None
        out: dict[str, list[tuple[float, int]]] = {}
        for run in runs if isinstance(runs, list) else []:
            try:
                if run["channel"] in self.channel_names:
                    out.setdefault(run["channel"], []).append(
                        (float(run["t"]), int(run["samples"])))
            except (KeyError, TypeError, ValueError):
                continue
        return out

    def overloaded(self, channel: str, t: np.ndarray) -> np.ndarray:
        """Boolean mask over times ``t`` (s): True within a run of ``channel`` the
        acquisition saw flagged overloaded (:meth:`overload_runs`)."""
        t = np.asarray(t, dtype=np.float64)
        mask = np.zeros(t.shape, dtype=bool)
        half = 0.5 / self.sample_rate_hz
        for start, n in self.overload_runs().get(channel, []):
            mask |= (t > start - half) & (t < start + n / self.sample_rate_hz - half)
        return mask

    def motor_positions(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The positions the actuator reported, or None when the recording holds none.

        They are read at their own, irregular times, slower than the samples.

        Returns
        -------
        t : ndarray of shape (n_reads,)
            Seconds on the recording's clock (that of ``t`` and the events): the middle
            of each read, between its request and its reply; both ends are in the
            sidecar's ``motor_positions``, with ``counts_per_revolution`` when known.
        position : ndarray of shape (n_reads,)
            Actuator units (counts), the unit of the ``move`` events' ``position``.
        """
        block = self.extra.get(MOTOR_POSITIONS)
        if block is None:
            return None
        try:
            names = [c["name"] for c in block["columns"]]
            reads = np.asarray(block["reads"], dtype=np.float64).reshape(-1, len(names))
            t = (reads[:, names.index("t_request")] + reads[:, names.index("t_reply")]) / 2
            return t, reads[:, names.index("position")]
        except (KeyError, TypeError, ValueError) as exc:
            raise RecordingError(f"malformed {MOTOR_POSITIONS!r} in sidecar: {exc!r}",
                                 path=self.name) from None

    def in_newtons(self) -> Recording:
        """This recording with its force channels in N (those in mN or kN scaled; the
        others, and a recording already in N, as they are)."""
        scale = np.array([NEWTONS_PER.get(c.unit, 1.0) for c in self.channels])
        if np.all(scale == 1.0):
            return self
        channels = tuple(Channel(c.name, "N") if c.unit in NEWTONS_PER else c
                         for c in self.channels)
        return replace(self, samples=self.samples * scale, channels=channels)

    @property
    def disqualified(self) -> tuple[Problem, ...]:
        """The problems that make this recording's numbers wrong (:data:`DISQUALIFYING`)."""
        return tuple(p for p in self.problems if p.kind in DISQUALIFYING)

    def with_problems(self, problems: Sequence[Problem]) -> Recording:
        return replace(self, problems=tuple(problems))

    def sidecar(self) -> dict[str, Any]:
        """The JSON sidecar as a dict (the exact schema of the interchange format)."""
        out: dict[str, Any] = {
            "sample_rate_hz": self.sample_rate_hz,
            "channels": [{"name": c.name, "unit": c.unit} for c in self.channels],
            "events": [e.to_json() for e in self.events],
            "metadata": self.metadata,
            "truth": self.truth,
        }
        out.update(self.extra)
        if self.problems:
            out["problems"] = [
                {"kind": p.kind, "channel": p.channel, "detail": p.detail} for p in self.problems
            ]
        return out


def validate(rec: Recording) -> list[Problem]:
    """Check a recording; return the problems found (empty when it is clean).

    Checks: time strictly increasing, runs of NaN/inf, dead (constant) channels,
    the sample intervals against ``sample_rate_hz``, time stamps that claim more missing
    samples than the file holds, forces beyond what a tactile sensor measures
    (:data:`FORCE_LIMIT_N`), events inside the time range, and unknown units. Dropped
    samples (gaps in ``t``) are reported as kind ``"gap"``, commands after the last sample
    (earlier ones inside) as ``"ends_early"``, samples the acquisition saw flagged
    overloaded as ``"overload"``, a declared rate a little off the data's as ``"rate_off"``;
    see :data:`INFORMATIONAL` and :data:`DISQUALIFYING`.
    """
    if rec.n_samples < 2:
        return [Problem("too_short", f"only {rec.n_samples} sample(s)")]
    problems = _time_problems(rec)
    problems += _event_problems(rec)
    problems += _overloads(rec)
    for j, ch in enumerate(rec.channels):
        problems += _channel_problems(rec.t, rec.samples[:, j], ch)
    return problems


def _time_problems(rec: Recording) -> list[Problem]:
    """What is wrong with ``t``: not finite, not increasing, at another rate than the
    sidecar's, gaps (plausible ones informational, ones claiming more missing samples than
    the file holds disqualifying) and samples sharing a slot of the grid."""
    dt = np.diff(rec.t)
    if not np.all(np.isfinite(rec.t)):
        return [Problem("nonfinite_time", "column 't' has NaN/inf values")]
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        return [Problem("nonmonotonic_time", f"time is not strictly increasing at row {i + 1} "
                        f"(t={rec.t[i]:.6g} s then {rec.t[i + 1]:.6g} s)")]
    problems = _rate_problems(rec, dt)
    if any(p.kind == "sample_rate" for p in problems):  # no grid to check the stamps against
        return problems
    nominal = 1.0 / rec.sample_rate_hz
    gaps = np.flatnonzero(dt > 1.5 * nominal)
    slots = (rec.t[-1] - rec.t[0]) * rec.sample_rate_hz + 1  # float: never overflows
    if slots > GRID_LIMIT * rec.n_samples:
        big = int(np.argmax(dt))
        problems.append(Problem(
            "time_span", f"its time stamps span {rec.t[-1] - rec.t[0]:.6g} s ({slots:.4g} "
            f"samples at {rec.sample_rate_hz:g} Hz) but the file holds {rec.n_samples} rows: "
            f"the gap after t={rec.t[big]:.6g} s (to {rec.t[big + 1]:.6g} s) claims more "
            "missing samples than the recording holds (a corrupted time stamp?)"))
        return problems
    if gaps.size:
        lost = int(np.sum(np.round(dt[gaps] / nominal) - 1))
        problems.append(Problem("gap", f"{gaps.size} gap(s) in t, about {lost} dropped "
                                f"sample(s); first at t={rec.t[gaps[0]]:.6g} s"))
    # the uniform grid every analysis uses keeps one sample per slot
    shared = rec.n_samples - np.unique(rec.grid_slots).size
    if shared:
        problems.append(Problem(
            "jitter", f"{shared} sample(s) share a slot of the {rec.sample_rate_hz:g}-Hz "
            "grid with a neighbour (their time stamps jitter by half a sample interval or "
            "more): one sample of each slot is used"))
    return problems


def _rate_problems(rec: Recording, dt: np.ndarray) -> list[Problem]:
    """The declared rate against the data's: the median interval more than
    :data:`RATE_TOLERANCE` off is disqualifying (``"sample_rate"``); the mean interval
    between neighbours (gaps left out) more than :data:`RATE_NOTE` off is named
    (``"rate_off"``)."""
    nominal = 1.0 / rec.sample_rate_hz
    median = float(np.median(dt))
    if abs(median - nominal) > RATE_TOLERANCE * nominal:
        return [Problem(
            "sample_rate",
            f"median sample interval {median * 1e3:.4g} ms does not match "
            f"sample_rate_hz={rec.sample_rate_hz:g} ({nominal * 1e3:.4g} ms)"
            + (" (is t in milliseconds? it must be seconds)"
               if abs(median / nominal - 1e3) < RATE_TOLERANCE * 1e3 else ""))]
    steady = dt[dt < 1.5 * nominal]
    rate = 1.0 / float(np.mean(steady)) if steady.size else rec.sample_rate_hz
    off = rec.sample_rate_hz / rate - 1.0
    if abs(off) > RATE_NOTE:
        return [Problem(
            "rate_off", f"the time stamps are {rate:.6g} Hz, {abs(off) * 100:.2g} % "
            f"{'under' if off > 0 else 'over'} the sidecar's sample_rate_hz="
            f"{rec.sample_rate_hz:g}: samples are placed on the sidecar's grid by their time "
            "stamps, leaving a slot empty (or shared) every "
            f"{1 / abs(off):.0f} samples; fix sample_rate_hz if it is wrong")]
    return []


def _event_problems(rec: Recording) -> list[Problem]:
    """Events outside the recording: disqualifying (``"events_outside"``) unless only
    commands after the last sample, the earlier ones inside (``"ends_early"``)."""
    outside = [e for e in rec.events
               if np.all(np.isfinite(rec.t)) and not rec.t[0] <= e.t <= rec.t[-1]]
    if not outside:
        return []
    e = outside[0]
    if e.t > rec.t[-1] and len(outside) < len(rec.events):
        # commands after the last sample, the earlier ones inside: the recording stopped
        # before its protocol did (an interrupted acquisition); what it holds is used
        return [Problem(
            "ends_early", f"{len(outside)} event(s) after the last sample at "
            f"t={rec.t[-1]:.6g} s, first {e.kind} {e.target or ''} at t={e.t:.6g} s: the "
            "recording stops before its protocol did (an interrupted acquisition?); what "
            "it holds is used")]
    return [Problem(
        "events_outside", f"{len(outside)} event(s) outside the recording's time range "
        f"{rec.t[0]:.6g}-{rec.t[-1]:.6g} s, first {e.kind} {e.target or ''} at "
        f"t={e.t:.6g} s (event times must be seconds from the start of the recording)")]


def _channel_problems(t: np.ndarray, x: np.ndarray, ch: Channel) -> list[Problem]:
    """One channel's problems: NaN/inf runs, constant (dead), an unknown unit, and forces
    (N) beyond :data:`FORCE_LIMIT_N`."""
    problems = []
    bad = ~np.isfinite(x)
    if bad.any():
        first = int(np.argmax(bad))
        problems.append(Problem("nonfinite", f"{int(bad.sum())} NaN/inf sample(s), first at "
                                f"t={t[first]:.6g} s", ch.name))
    finite = x[~bad]
    if finite.size and float(np.ptp(finite)) <= DEAD_CHANNEL_SPAN:
        problems.append(Problem("dead_channel", f"constant at {finite[0]:.6g} {ch.unit} (dead?)",
                                ch.name))
    if ch.unit == "N" and finite.size and float(np.max(np.abs(finite))) > FORCE_LIMIT_N:
        i = int(np.argmax(np.abs(np.where(bad, 0.0, x))))
        problems.append(Problem(
            "force_range", f"{x[i]:.4g} N at t={t[i]:.6g} s: beyond what a tactile sensor "
            f"measures (|F| <= {FORCE_LIMIT_N:g} N); is the unit wrong (mN, or counts, written "
            "as N)?", ch.name))
    if ch.unit not in KNOWN_UNITS:
        problems.append(Problem("unit", f"unknown unit {ch.unit!r}; expected one of "
                                f"{sorted(KNOWN_UNITS)}", ch.name))
    return problems


def _overloads(rec: Recording) -> list[Problem]:
    """Kind ``"overload"`` per channel the acquisition listed as overloaded (the DAQ's
    status bits: its values may be clipped), and per sensor whose runs were too many to
    list (those samples are neither named nor left out of the fits)."""
    problems = [Problem("overload", f"{sum(n for _, n in runs)} sample(s) overloaded by the "
                        f"DAQ's status, first at t={runs[0][0]:.6g} s: their values may be "
                        "clipped", name)
                for name, runs in rec.overload_runs().items()]
    acq = rec.extra.get("acquisition")
    sensors = acq.get("sensors") if isinstance(acq, dict) else None
    for sensor in sensors if isinstance(sensors, list) else []:
        unlisted = sensor.get("overloads_unlisted") if isinstance(sensor, dict) else None
        if isinstance(unlisted, int) and unlisted > 0:
            problems.append(Problem(
                "overload", f"sensor {sensor.get('name')!r}: {unlisted} more overloaded "
                "run(s) than the sidecar lists; their samples are not marked and the fits "
                "keep them"))
    return problems


#: Problems that are facts of a data link rather than defects: reported, never raised.
#: Dropped rows and NaN bursts are expected of lab recordings (a serial link loses
#: samples); segmentation and fitting mask them. A recording that ends before its last
#: commands (an interrupted acquisition keeps every row it flushed and every command it
#: sent) is used as far as it goes.
INFORMATIONAL = frozenset({"gap", "nonfinite", "ends_early", "jitter", "overload",
                           "rate_off"})
#: Problems that make every number taken from the recording wrong: commands skip such a
#: recording, naming it and the problem, unless asked to stop (``--strict``).
DISQUALIFYING = frozenset({"too_short", "nonfinite_time", "nonmonotonic_time", "sample_rate",
                           "events_outside", "truncated", "time_span", "force_range"})


def _check(rec: Recording, path: PathType, on_error: OnError) -> Recording:
    problems = validate(rec)
    if on_error == "raise":
        fatal = [p for p in problems if p.kind not in INFORMATIONAL]
        if fatal:
            p = fatal[0]
            more = f" (and {len(fatal) - 1} more problem(s))" if len(fatal) > 1 else ""
            raise RecordingError(p.detail + more, path=path, channel=p.channel)
    elif on_error != "flag":
        raise ValueError(f"on_error must be 'raise' or 'flag', not {on_error!r}")
    return rec.with_problems(problems)


def recording_paths(path: PathType) -> tuple[Path, Path]:
    """``<name>.csv`` and ``<name>.json`` of the recording at ``path`` (either file, or the
    name: which may hold dots, ``run_1.5mm``)."""
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".csv", ".json") else p
    return stem.with_name(stem.name + ".csv"), stem.with_name(stem.name + ".json")


def looks_like_fabricslide(csv_path: Path) -> bool:
    """Whether ``csv_path``'s header is a FabricSlide slide's (``timestamp, proximity1,
    ...``): a file of another dataset kind, read as ``fabricslide:PATH``."""
    try:
        with open(csv_path, errors="replace") as f:
            head = f.readline(4096)
    except OSError:
        return False
    return [c.strip() for c in head.split(",")[:2]] == ["timestamp", "proximity1"]


def _read_sidecar(json_path: Path) -> dict[str, Any]:
    if not json_path.exists():
        csv_path = json_path.with_suffix(".csv")
        if looks_like_fabricslide(csv_path):
            raise RecordingError(f"a FabricSlide slide, not a recording with a sidecar: read "
                                 f"it as fabricslide:{csv_path}", path=csv_path)
        raise RecordingError("sidecar file is missing (every <name>.csv needs <name>.json)",
                             path=json_path)
    try:
        side = json.loads(json_path.read_text())
    except json.JSONDecodeError as exc:
        raise RecordingError(f"sidecar is not valid JSON: {exc}", path=json_path) from None
    if not isinstance(side, dict):
        raise RecordingError("sidecar must be a JSON object", path=json_path)
    for key in REQUIRED_SIDECAR_FIELDS:
        if key not in side:
            raise RecordingError(f"sidecar is missing the field {key!r}", path=json_path)
    rate = side["sample_rate_hz"]
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate) \
            or rate <= 0:
        raise RecordingError(f"sample_rate_hz must be a positive number, not {rate!r}",
                             path=json_path)
    for key, kind in (("channels", list), ("events", list), ("metadata", dict),
                      ("truth", dict)):
        if key in side and not isinstance(side[key], kind):
            want = "a list" if kind is list else "an object"
            raise RecordingError(f"sidecar field {key!r} must be {want}, not "
                                 f"{json.dumps(side[key])[:40]}", path=json_path)
    for i, ch in enumerate(side["channels"]):
        if not isinstance(ch, dict) or "name" not in ch or "unit" not in ch:
            raise RecordingError(f"channels[{i}] needs 'name' and 'unit', got {ch!r}",
                                 path=json_path)
    Rig.from_metadata(side.get("metadata") or {}, json_path)  # its facts, checked
    return side


def _why_unparsable(csv_path: Path, exc: Exception) -> str:
    """Name the first cell that is not a number (row counted from 1 after the header) and
    hint at the separator; else pandas' own words."""
    try:
        head = csv_path.read_text(errors="replace").splitlines()[:1]
        raw = pd.read_csv(csv_path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except (ValueError, OSError):
        return f"cannot parse CSV: {exc}"
    if head and "," not in head[0]:
        for sep, name in ((";", "';'"), ("\t", "tabs")):
            if sep in head[0]:
                return (f"cannot parse CSV: the header {head[0][:60]!r} looks separated by "
                        f"{name}; frictionfit reads comma-separated values")
    for col in raw.columns:
        cells = raw[col].str.strip()
        bad = pd.to_numeric(cells.where(~cells.str.lower().isin(["", "nan"]), "0"),
                            errors="coerce").isna()
        if bad.any():
            row = int(np.argmax(bad.to_numpy()))
            return (f"cannot parse CSV: data row {row + 1} (line {row + 2}), column {col!r}: "
                    f"{raw[col].iloc[row]!r} is not a number")
    return f"cannot parse CSV: {exc}"


def check_newtons(name: str, channels: Sequence[Channel],
                  names: Sequence[str] | None = None) -> None:
    """RecordingError naming recording ``name`` and the first of its ``channels`` (those
    ``names``, default all) not in N: a fit's parameters are forces in N."""
    for c in channels:
        if c.unit != "N" and (names is None or c.name in names):
            raise RecordingError(
                f"unit {c.unit!r}, not N: a fit's parameters are forces in N (channels in mN or "
                "kN are read in N; raw counts need the sensor's sensitivity: frictionfit "
                "acquire --sensitivity)", path=name, channel=c.name)


def read_recording(path: PathType, *, on_error: OnError = "raise") -> Recording:
    """Read ``<name>.csv`` + ``<name>.json`` (either path, or the stem) and validate it;
    force channels in mN or kN are read in N (:meth:`Recording.in_newtons`).

    Parameters
    ----------
    path : str or PathLike
        The CSV, the JSON sidecar, or their common stem.
    on_error : {"raise", "flag"}, default "raise"
        ``"raise"``: a :class:`~frictionfit.errors.RecordingError` naming the file,
        channel and problem. ``"flag"``: keep the data and record the problems in
        ``Recording.problems`` (NaN stays NaN; fitting masks it).

    Returns
    -------
    Recording
    """
    if Path(path).suffix not in (".csv", ".json") and Path(path).is_file():
        raise RecordingError("not a recording: frictionfit reads <name>.csv with its "
                             "<name>.json sidecar", path=path)
    csv_path, json_path = recording_paths(path)
    if not csv_path.exists() and not json_path.exists():
        raise RecordingError("no such recording: neither it nor its .json sidecar exists",
                             path=csv_path)
    side = _read_sidecar(json_path)
    if not csv_path.exists():
        raise RecordingError("data file is missing", path=csv_path)
    try:
        frame = pd.read_csv(csv_path, dtype=np.float64, na_values=["nan", "NaN", ""],
                            skipinitialspace=True)  # "t, thumb_x, ..." as well
    except ValueError as exc:  # pandas' parser errors are ValueErrors too
        raise RecordingError(_why_unparsable(csv_path, exc), path=csv_path) from None
    names = [c["name"] for c in side["channels"]]
    if list(frame.columns) != ["t", *names]:
        raise RecordingError(
            f"CSV columns {list(frame.columns)} do not match ['t'] + sidecar channels {names}",
            path=csv_path,
        )
    known = {"sample_rate_hz", "channels", "events", "metadata", "truth", "problems"}
    events = _events(side.get("events", []), json_path)
    values = frame.to_numpy(dtype=np.float64)
    rec = Recording(
        t=values[:, 0],
        samples=values[:, 1:],
        sample_rate_hz=float(side["sample_rate_hz"]),
        channels=tuple(Channel(c["name"], c["unit"]) for c in side["channels"]),
        events=events,
        metadata=dict(side.get("metadata") or {}),
        truth=dict(side.get("truth") or {}),
        name=csv_path.stem,
        extra={k: v for k, v in side.items() if k not in known},
    )
    return _check(rec.in_newtons(), csv_path, on_error)


def _events(items: list, json_path: Path) -> tuple[Event, ...]:
    """The sidecar's ``events``; RecordingError naming the first malformed one (its index,
    what it holds and what is wrong)."""
    events = []
    for i, e in enumerate(items):
        try:
            if not isinstance(e, dict):
                raise TypeError("not an object")
            missing = [k for k in ("t", "kind") if k not in e]
            if missing:
                raise KeyError(f"no {' or '.join(repr(k) for k in missing)}")
            events.append(Event.from_json(e))
        except (KeyError, TypeError, ValueError) as exc:
            why = exc.args[0] if isinstance(exc, KeyError) else str(exc)
            raise RecordingError(f"malformed event {i} in sidecar {json.dumps(e)[:80]}: {why} "
                                 "(an event needs 't' in s and 'kind')", path=json_path) from None
    return tuple(events)


def write_recording(rec: Recording, path: PathType, *, decimals: int | None = None) -> Path:
    """Write ``<path>.csv`` and ``<path>.json``; return the CSV path.

    ``decimals=None`` writes every float exactly (round-trips bit for bit);
    ``decimals=3`` writes millinewtons, as the lab's files do.
    """
    csv_path, json_path = recording_paths(path)
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    fmt = "%.17g" if decimals is None else f"%.{decimals}f"
    frame = pd.DataFrame(rec.samples, columns=list(rec.channel_names))
    frame.insert(0, "t", rec.t)
    frame.to_csv(csv_path, index=False, float_format=fmt, na_rep="nan")
    json_path.write_text(json.dumps(rec.sidecar(), indent=1, default=_json_default))
    return csv_path


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"cannot write {type(obj).__name__} to a sidecar")


def iter_recording_paths(folder: PathType) -> Iterator[Path]:
    """The CSV files of a folder's recordings, sorted by name."""
    yield from sorted(Path(folder).glob("*.csv"))


def read_dataset(folder: PathType, *, on_error: OnError = "flag",
                 strict: bool = False) -> list[Recording]:
    """Read every recording in a folder (sorted by name).

    ``on_error="flag"`` (the default here) keeps damaged recordings with their
    problems listed. A file that cannot be read, whose channels differ from the
    folder's first readable recording, or whose problems make its numbers wrong
    (:data:`DISQUALIFYING`) is skipped with a :class:`DatasetWarning` naming it and
    why, so one bad file never sinks a dataset; ``strict=True`` raises instead.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder of recordings")
    paths = list(iter_recording_paths(folder))
    if not paths:
        raise DatasetError(f"{folder}: no <name>.csv + <name>.json recordings found")
    recs: list[Recording] = []
    why: list[str] = []
    for path in paths:
        try:
            rec = read_recording(path, on_error=on_error)
            if rec.disqualified:
                p = rec.disqualified[0]
                raise RecordingError(str(p), path=path, channel=p.channel)
            if recs and rec.channels != recs[0].channels:
                mine = [f"{c.name} [{c.unit}]" for c in rec.channels]
                theirs = [f"{c.name} [{c.unit}]" for c in recs[0].channels]
                raise RecordingError(f"channels {mine} differ from {theirs} of "
                                     f"{recs[0].name} (units mismatch?)", path=path)
        except RecordingError as exc:
            if strict:
                raise DatasetError(str(exc)) from None
            warnings.warn(f"skipped {exc}", DatasetWarning, stacklevel=2)
            why.append(exc.problem)
            continue
        recs.append(rec)
    if not recs:
        raise DatasetError(_none_usable(folder, paths, why))
    return recs


def _none_usable(folder: Path, paths: list[Path], why: list[str]) -> str:
    """Why no recording of ``folder`` could be used: its files another dataset kind's, or
    the commonest reasons, counted."""
    if all(looks_like_fabricslide(p) for p in paths):
        return (f"{folder}: its {len(paths)} .csv files are FabricSlide slides, not recordings "
                f"with sidecars: read the folder as fabricslide:{folder}")
    counts = pd.Series(why, dtype=object).value_counts()
    reasons = "; ".join(f"{n} x {reason}" for reason, n in counts.head(3).items())
    more = f"; and {len(counts) - 3} other reason(s)" if len(counts) > 3 else ""
    return f"{folder}: none of its {len(paths)} recordings could be used: {reasons}{more}"


class DatasetWarning(UserWarning):
    """A recording was left out of a dataset (the message names it and why)."""


def kept_per_recording(fn: Callable) -> Callable:
    """``fn(rec, *args)`` computed once per recording object and ``args`` (arrays by their
    contents), kept while the recording lives: what several readers of one recording ask
    for (its faults, motions, motor timing, content hash) is computed once."""
    kept: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

    @functools.wraps(fn)
    def once(rec: Recording, *args):
        key = tuple((a.dtype.str, a.shape, a.tobytes()) if isinstance(a, np.ndarray) else a
                    for a in args)
        own = kept.setdefault(rec, {})
        if key not in own:
            own[key] = fn(rec, *args)
        return own[key]

    return once
