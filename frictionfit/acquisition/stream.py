"""One sensor as a stream of numbered samples that survives a pulled cable.

A :class:`SensorStream` owns an :class:`~frictionfit.acquisition.sensor.OptoForceSensor`,
turns its frames into samples on the recording's grid (sample ``k`` is at
``k / rate_hz`` s), converts counts to newtons, and when the link dies keeps
trying to open the port again; every hole in the grid is kept as a :class:`Gap`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from frictionfit.acquisition.frames import DataFrame, axis_names
from frictionfit.acquisition.sensor import OptoForceSensor, speed_code
from frictionfit.errors import AcquisitionError
from frictionfit.recording import Channel

__all__ = ["Gap", "SensorStream"]

#: At most this many gaps, and as many overloaded runs, are listed per sensor; the rest
#: are only counted (``gaps_unlisted``, ``overloads_unlisted``).
MAX_GAPS_LISTED = 1000
#: A connected sensor silent this long (s) no longer holds back the other sensors' rows;
#: a frame whose counter moved on this much less than the host clock since the previous
#: frame is placed by its arrival (the DAQ stopped counting while silent). The port's
#: buffers hold ~0.25 s at 1 kHz: a host that stops reading for longer loses frames,
#: and the counter says how many, so a late frame is never taken for a silence.
SILENT_S = 1.0
#: A frame whose counter moved on this much more (s) than the host clock since the
#: previous frame cannot have been sampled yet: the counter restarted, and the frame is
#: placed by its arrival. (Between frames the host clock runs ahead when frames wait;
#: the counter never can, whatever the clocks' drift.)
AHEAD_S = 0.5


@dataclass(frozen=True)
class Gap:
    """Missing samples: the first one's time ``t`` (s), how many, and why."""

    t: float
    samples: int
    cause: str

    def to_json(self) -> dict[str, object]:
        return {"t": round(self.t, 6), "samples": self.samples, "cause": self.cause}


class SensorStream:
    """A sensor's samples as ``(k, values)`` arrays, with reconnection and damage counts.

    Parameters
    ----------
    url : str
        The port, as :func:`serial.serial_for_url` takes it.
    name : str
        Prefix of the channel names (``<name>_x``, ``<name>_y``, ...).
    rate_hz : float
        Nominal rate, one of the DAQ's (1000, 333, 100, 30, 10 Hz); kept exactly as
        ``1000 / speed code`` (333 Hz is 1000/3 Hz).
    filter_code, zero :
        Passed to :meth:`OptoForceSensor.configure`.
    sensitivity : path, optional
        JSON sensitivity file (counts per N by serial number); raw counts without it.
    retry_s : float
        Seconds between attempts to reopen a lost port.
    """

    def __init__(self, url: str, name: str, rate_hz: float, *, filter_code: int = 0,
                 zero: bool = False, sensitivity: str | Path | None = None,
                 retry_s: float = 0.25, clock: Callable[[], float] = time.monotonic) -> None:
        self.url, self.name = url, name
        self.rate_hz = 1000.0 / speed_code(rate_hz)  # exact: 333 Hz is 1000/3
        self.filter_code, self.zero, self.sensitivity = filter_code, zero, sensitivity
        self.retry_s, self.clock = retry_s, clock
        self.sensor: OptoForceSensor | None = None
        self.serial_number: str | None = None
        self.scale: np.ndarray | None = None
        self.channels: tuple[Channel, ...] = ()
        self.gaps: list[Gap] = []
        self.gaps_unlisted = 0
        self.frames_received = 0
        self.frames_flagged = 0
        self.frames_overloaded = 0
        self.overloads: list[dict[str, object]] = []  # {"channel", "k", "samples"} runs
        self._open_overload: dict[str, dict[str, object]] = {}
        self.overloads_unlisted = 0
        self.samples_lost = 0
        self.reconnects = 0
        self.reconnect_failures = 0
        self._closed = False
        self.first_k: int | None = None
        self.last_k: int | None = None
        self._done = {"corrupted": 0, "discarded": 0, "overflow": 0}
        self._pending: list[tuple[float, DataFrame]] = []
        self.last_arrival: float | None = None
        self._down_since: float | None = None
        self._down_reason = ""
        self._last_try = -math.inf
        self._new_link = True
        self._restarted = False

    # -- the link -------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port, ask the serial number, configure and start reading."""
        sensor = OptoForceSensor(self.url)
        sensor.open()
        try:
            serial_number = sensor.query_serial()
            sensor.configure(self.rate_hz, self.filter_code, self.zero)
        except AcquisitionError:
            sensor.close()
            raise
        if None not in (self.serial_number, serial_number) and (
                serial_number != self.serial_number):
            sensor.close()
            raise AcquisitionError(f"{self.url}: sensor {serial_number!r} answered where "
                                   f"{self.serial_number!r} was recording")
        self.serial_number = self.serial_number or serial_number
        sensor.start()
        self.sensor, self._new_link, self._down_since = sensor, True, None

    def wait_first_frame(self, timeout_s: float = 1.0) -> None:
        """Block until the first frame arrives; then the channels are known."""
        assert self.sensor is not None, "connect() first"
        deadline = self.clock() + timeout_s
        while not self._pending and self.clock() < deadline:
            self._pending = self.sensor.received()
            time.sleep(0.002)
        if not self._pending:
            raise AcquisitionError(f"{self.url}: configured, but no data frame within "
                                   f"{timeout_s} s")
        n = len(self._pending[0][1].counts)
        per_unit = self.sensor.counts_per_unit(self.sensitivity, n)
        self.scale = None if per_unit is None else 1.0 / np.asarray(per_unit)
        axes = axis_names(n)
        units = ["counts"] * n if per_unit is None else [
            "N m" if a.startswith("t") else "N" for a in axes]
        self.channels = tuple(Channel(f"{self.name}_{a}", u) for a, u in zip(axes, units,
                                                                             strict=True))

    @property
    def first_frame_time(self) -> float | None:
        return None if self.sensor is None else self.sensor.first_frame_time

    @property
    def connected(self) -> bool:
        return self._down_since is None

    @property
    def silent(self) -> bool:
        """Connected, but no frame for :data:`SILENT_S` (the DAQ stopped sending)."""
        return (self.connected and self.last_arrival is not None
                and self.clock() - self.last_arrival > SILENT_S)

    def _retire(self) -> None:
        """Keep the counts of a link that ended, and close it."""
        sensor = self.sensor
        if sensor is None:
            return
        sensor.close()
        self._done["corrupted"] += sensor.parser.frames_corrupted
        self._done["discarded"] += sensor.parser.bytes_discarded
        self._done["overflow"] += sensor.frames_overflow
        self.sensor = None

    def _link_ended(self) -> bool:
        """True when the reader thread stopped on an error (the cable was pulled)."""
        sensor = self.sensor
        return sensor is not None and not sensor.alive and sensor.error is not None

    def _reconnect_if_due(self) -> None:
        if self.sensor is None and not self._closed and (
                self.clock() - self._last_try >= self.retry_s):
            self._last_try = self.clock()
            try:
                self.connect()
                self.reconnects += 1
            except AcquisitionError:
                self.reconnect_failures += 1

    # -- samples -----------------------------------------------------------------
    def _gap(self, k: int, n: int, cause: str) -> None:
        self.samples_lost += n
        if len(self.gaps) < MAX_GAPS_LISTED:
            self.gaps.append(Gap(k / self.rate_hz, n, cause))
        else:
            self.gaps_unlisted += 1

    def _start_index(self, arrival: float, t0: float, floor: int, cause: str) -> int:
        """Grid index of a frame that starts a stretch (a new link, a restarted counter):
        its ``arrival`` on the host clock, but after this stream's last sample and no
        earlier than ``floor``; the samples skipped are a gap for ``cause`` (listed even
        when none is, so the break is on record)."""
        k = max(round((arrival - t0) * self.rate_hz), floor)
        if self.last_k is None:
            return k
        k = max(k, self.last_k + 1)
        self._gap(self.last_k + 1, k - self.last_k - 1, cause)
        return k

    def poll(self, t0: float, floor: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """New samples: indices ``k`` (n,) on the grid started at host time ``t0``, values (n, c).

        Values are in the channels' units; frames whose status flags a DAQ or sensor
        error become NaN rows (counted in ``frames_flagged``). When the link has ended,
        the frames it received are numbered on it before the port is reopened. A new
        link starts at ``floor`` or later: the first row not yet written, when other
        sensors' rows went on while this one was away (their clocks drift from the
        host's by tens of ms an hour); so does a frame whose counter moved on
        :data:`SILENT_S` less than the host clock (the DAQ's counter stopped while it was
        silent), or would put it among rows already written, and one whose counter jumped
        :data:`AHEAD_S` further than the host clock (restarted: the DAQ is then configured
        again, as it came back at its power-up rate).
        """
        received, self._pending = self._pending, []
        ended = []
        if self._link_ended():
            assert self.sensor is not None
            ended.append(self._number(received + self.sensor.received(), t0, floor))
            received = []
            self._down_reason, self._down_since = self.sensor.error or "", self.clock()
            self._retire()
        self._reconnect_if_due()
        if self.sensor is not None:
            received += self.sensor.received()
        ks, values = zip(*ended, self._number(received, t0, floor), strict=True)
        if self._restarted:
            self._configure_again()
        return np.concatenate(ks), np.concatenate(values)

    def _configure_again(self) -> None:
        """Send the configuration again to a DAQ whose counter restarted: it came back from
        a power cycle at its power-up rate and filter (100 Hz, 15 Hz by the reference), not
        at the recording's. Listed with the gaps either way (0 samples)."""
        self._restarted = False
        if self.sensor is None or self.last_k is None:
            return
        try:
            self.sensor.reconfigure(self.rate_hz, self.filter_code)
            cause = ("the restarted DAQ was configured again (rate and filter; a hardware "
                     "zero is not taken again)")
        except AcquisitionError as exc:
            cause = (f"the restarted DAQ could not be configured again ({exc}): its samples "
                     "may come at its power-up rate")
        self._gap(self.last_k + 1, 0, cause)

    def _index(self, arrival: float, f: DataFrame, t0: float, floor: int) -> int:
        """Grid index of frame ``f``: by its counter, unless the host clock rules it out."""
        if self._new_link:
            self._new_link = False
            return self._start_index(arrival, t0, floor,
                                     f"link lost ({self._down_reason}); reconnected")
        k = self.last_k + 1 + f.lost_before
        assert self.last_arrival is not None  # set with last_k
        silence = arrival - self.last_arrival
        ahead = (k - self.last_k) / self.rate_hz - silence
        if ahead > AHEAD_S:
            self._restarted = True
            return self._start_index(arrival, t0, floor, f"the DAQ's counter jumped "
                                     f"{ahead:.1f} s further than the host clock "
                                     "(restarted?)")
        if ahead < -SILENT_S or k < floor:
            return self._start_index(arrival, t0, floor, f"the DAQ fell silent for "
                                     f"{silence:.2f} s and its counter with it")
        if f.lost_before:
            self._gap(self.last_k + 1, f.lost_before, "counter gap (corrupted or dropped "
                      "frames)")
        return k

    def _overloaded(self, k: int, axes: tuple[str, ...]) -> None:
        """Extend, or start, each overloaded channel's run of samples at grid index ``k``.

        The status word names axes; on a 4-channel DAQ (one word for all four) every
        channel of a named axis is taken as overloaded."""
        for channel in self.channels:
            if not channel.name.endswith(axes):
                continue
            run = self._open_overload.get(channel.name)
            if run is not None and run["k"] + run["samples"] == k:
                run["samples"] += 1
                continue
            run = self._open_overload[channel.name] = {"channel": channel.name, "k": k,
                                                       "samples": 1}
            if len(self.overloads) < MAX_GAPS_LISTED:
                self.overloads.append(run)
            else:
                self.overloads_unlisted += 1

    def _number(self, received: list[tuple[float, DataFrame]], t0: float, floor: int
                ) -> tuple[np.ndarray, np.ndarray]:
        """Grid indices (n,) and values (n, c) of one link's frames, in order."""
        ks = np.empty(len(received), dtype=np.int64)
        values = np.empty((len(received), len(self.channels)))
        for i, (arrival, f) in enumerate(received):
            ks[i] = self.last_k = self._index(arrival, f, t0, floor)
            self.last_arrival = arrival
            if self.first_k is None:
                self.first_k = self.last_k
            values[i] = f.counts if f.valid else np.nan
            self.frames_flagged += not f.valid
            self.frames_overloaded += bool(f.overloaded)
            if f.overloaded:
                self._overloaded(self.last_k, f.overloaded)
        if self.scale is not None:
            values *= self.scale
        self.frames_received += len(received)
        return ks, values

    def close(self) -> None:
        """Stop the DAQ streaming (reading until it acknowledges) and close the port.

        Frames that arrived before the acknowledge stay pending for a last :meth:`poll`.
        """
        self._closed = True
        if self.sensor is not None:
            self.sensor.stop(self.filter_code)
            self._pending += self.sensor.received()
        self._retire()

    # -- report ----------------------------------------------------------------
    @property
    def frames_corrupted(self) -> int:
        live = self.sensor.parser.frames_corrupted if self.sensor is not None else 0
        return self._done["corrupted"] + live

    def summary(self) -> dict[str, object]:
        """This sensor's part of the sidecar's ``acquisition`` object."""
        live = self.sensor
        span = (self.last_k - self.first_k + 1) / self.rate_hz if self.first_k is not None else 0.0
        return {
            "name": self.name,
            "port": self.url,
            "sensor_serial": self.serial_number,
            "frames_valid": self.frames_received,
            "frames_corrupted": self.frames_corrupted,
            "frames_flagged": self.frames_flagged,
            "frames_overloaded": self.frames_overloaded,
            "overloads": [{"channel": r["channel"], "t": round(r["k"] / self.rate_hz, 6),
                           "samples": r["samples"]} for r in self.overloads],
            "overloads_unlisted": self.overloads_unlisted,
            "samples_lost": self.samples_lost,
            "bytes_discarded": self._done["discarded"] + (
                live.parser.bytes_discarded if live is not None else 0),
            "queue_overflow": self._done["overflow"] + (
                live.frames_overflow if live is not None else 0),
            "reconnects": self.reconnects,
            "connected": self.connected,
            "silent": self.silent,
            "rate_hz_achieved": round(self.frames_received / span, 3) if span else 0.0,
            "gaps": [g.to_json() for g in self.gaps],
            "gaps_unlisted": self.gaps_unlisted,
        }
