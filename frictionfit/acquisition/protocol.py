"""The rubbing protocol: ``move p2`` / ``move p1`` commands on a fixed schedule.

As in the rubbing-lab measurements: the fingers start closed at ``p1``; motion
``k`` sends ``move p2`` at ``start_s + 2 k dwell_s`` and ``move p1`` one
``dwell_s`` later; the recording ends ``dwell_s`` after the last command. Each
command is written as an event ``{"t": ..., "kind": "move", "target": "p2"}``
(plus the commanded ``position``) at the recording time it was sent; a command
the actuator refuses ends the protocol with a ``protocol_error`` event.

Between the commands the actuator's present position is read at a steady rate and
kept in the sidecar's ``motor_positions`` (:class:`PositionLog`): the drive the
contact sees, which a compliant drive with play makes differ from the commands.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from frictionfit.acquisition.actuator import Actuator
from frictionfit.acquisition.recorder import RecordingWriter
from frictionfit.recording import MOTOR_COLUMNS, MOTOR_POSITIONS, Event

__all__ = ["PositionLog", "ProtocolRunner", "RubbingProtocol"]


@dataclass(frozen=True)
class RubbingProtocol:
    """Positions ``p1``/``p2`` (actuator units), ``motions``, ``dwell_s`` and ``start_s`` (s).

    Examples
    --------
    >>> RubbingProtocol(0.0, 1.0, motions=2, dwell_s=1.0).schedule()
    [(0.05, 'p2'), (1.05, 'p1'), (2.05, 'p2'), (3.05, 'p1')]
    """

    p1: float
    p2: float
    motions: int = 5
    dwell_s: float = 1.0
    start_s: float = 0.05

    def __post_init__(self) -> None:
        if self.motions < 1 or self.dwell_s <= 0 or self.start_s < 0:
            raise ValueError(f"need motions >= 1, dwell_s > 0 and start_s >= 0, got "
                             f"{self.motions}, {self.dwell_s}, {self.start_s}")

    def schedule(self) -> list[tuple[float, str]]:
        """``(t, target)`` of every command, t in s from the start of the recording."""
        return [(round(self.start_s + i * self.dwell_s, 9), "p2" if i % 2 == 0 else "p1")
                for i in range(2 * self.motions)]

    @property
    def duration_s(self) -> float:
        """Length of the recording: the last command plus one dwell, s."""
        return self.start_s + 2 * self.motions * self.dwell_s


class PositionLog:
    """The actuator's positions as read, each with the recording times of its request and
    reply (s); a failed read is counted, with the last one's words, and never stops anything.

    Filled by the protocol's thread while the writer takes snapshots (:meth:`to_json`).
    The sidecar, reads included, is rewritten whole at every flush: right for a protocol
    of minutes (3 000 reads a minute at 50 Hz), costly for hours.

    Examples
    --------
    >>> log = PositionLog(50.0, counts_per_revolution=4096)
    >>> log.add(0.012, 0.031, 1000.0)
    >>> log.fail(0.052, "no status")
    >>> log.to_json()["reads"]
    [[0.012, 0.031, 1000.0]]
    >>> log.summary()
    'motor positions: 1 read (asked 50 Hz), 1 failed (last at t=0.052 s: no status)'
    """

    def __init__(self, rate_hz: float, counts_per_revolution: int | None = None) -> None:
        self.rate_hz, self.counts_per_revolution = rate_hz, counts_per_revolution
        self.reads: list[tuple[float, float, float]] = []
        self.failed = 0
        self.last_failure: str | None = None
        self._lock = threading.Lock()

    def add(self, t_request: float, t_reply: float, position: float) -> None:
        with self._lock:
            self.reads.append((round(t_request, 6), round(t_reply, 6), position))

    def fail(self, t: float, detail: str) -> None:
        with self._lock:
            self.failed += 1
            self.last_failure = f"t={t:.3f} s: {detail}"

    def to_json(self) -> dict[str, Any]:
        """The sidecar's ``motor_positions``: columns, reads, the rate asked for, failures."""
        with self._lock:
            out: dict[str, Any] = {"columns": [dict(c) for c in MOTOR_COLUMNS],
                                   "reads": [list(r) for r in self.reads],
                                   "rate_hz_requested": self.rate_hz, "reads_failed": self.failed}
            if self.last_failure is not None:
                out["last_failure"] = self.last_failure
        if self.counts_per_revolution is not None:
            out["counts_per_revolution"] = self.counts_per_revolution
        return out

    def summary(self) -> str:
        """One line: how many reads, at what rate, how many failed and the last failure."""
        with self._lock:
            n, failed, last = len(self.reads), self.failed, self.last_failure
            span = self.reads[-1][0] - self.reads[0][0] if n > 1 else 0.0
        rate = f" at {(n - 1) / span:.1f} Hz" if span > 0 else ""
        out = f"motor positions: {n} read{rate} (asked {self.rate_hz:g} Hz), {failed} failed"
        return out + (f" (last at {last})" if last else "")


class ProtocolRunner:
    """Sends the protocol's commands on time from its own thread, logging each as an event,
    and reads the actuator's position between them.

    Timing does not depend on the recording loop (disk flushes can take tens of ms):
    the thread sleeps until each command or read is due on the recording clock. No read
    starts closer to the next command than the actuator's ``position_timeout_s`` (or
    the last read's round trip, if longer), so a read, even a failed one, does not
    delay a command; the finger rests there, so little is missed. With
    ``position_rate_hz`` 0 nothing is read and :attr:`positions` is None.
    """

    def __init__(self, protocol: RubbingProtocol, actuator: Actuator,
                 clock: Callable[[], float] = time.monotonic,
                 position_rate_hz: float = 0.0) -> None:
        self.protocol, self.actuator, self.clock = protocol, actuator, clock
        self.error: str | None = None
        self.positions = PositionLog(position_rate_hz, actuator.counts_per_revolution) if (
            position_rate_hz > 0) else None
        self._read_s = 0.0
        self._halt = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, t0: float, writer: RecordingWriter) -> Callable[[], None]:
        """Run the schedule against the recording clock ``clock() - t0`` (s); return a stop."""
        if self.positions is not None:
            writer.attach(MOTOR_POSITIONS, self.positions.to_json)
        self._thread = threading.Thread(target=self._run, args=(t0, writer),
                                        name="rubbing protocol", daemon=True)
        self._thread.start()
        return self.stop

    def _run(self, t0: float, writer: RecordingWriter) -> None:
        pending = self.protocol.schedule()
        period = 1.0 / self.positions.rate_hz if self.positions is not None else math.inf
        next_read = 0.0 if self.positions is not None else math.inf
        while (pending or self.positions is not None) and not self._halt.is_set():
            now = self.clock() - t0
            due = pending[0][0] if pending else math.inf
            if now >= due:
                if not self._command(t0, writer, pending.pop(0)[1]):
                    pending.clear()
                continue
            margin = max(self.actuator.position_timeout_s, self._read_s)
            read_at = next_read if next_read < due - margin else math.inf
            if read_at <= now:
                self._read(t0)
                next_read = max(next_read + period, self.clock() - t0)
            elif self._halt.wait(min(due, read_at) - now):
                return

    def _command(self, t0: float, writer: RecordingWriter, target: str) -> bool:
        """Send one command and log it; False when the actuator refused it."""
        position = self.protocol.p2 if target == "p2" else self.protocol.p1
        t = self.clock() - t0
        try:
            self.actuator.move_to(position)
        except Exception as exc:  # kept as an event in the sidecar; the recording goes on
            self.error = f"move {target} at t={t:.3f} s failed: {exc}"
            writer.add_event(Event(round(t, 6), "protocol_error", target, {"detail": str(exc)}))
            return False
        writer.add_event(Event(round(t, 6), "move", target, {"position": position}))
        return True

    def _read(self, t0: float) -> None:
        """Read the position once into :attr:`positions`; a failure is only counted."""
        assert self.positions is not None
        t_request = self.clock() - t0
        try:
            position = float(self.actuator.position())
        except Exception as exc:  # a lost reading must never stop the recording
            self.positions.fail(t_request, str(exc))
            return
        t_reply = self.clock() - t0
        self.positions.add(t_request, t_reply, position)
        self._read_s = t_reply - t_request

    def stop(self) -> None:
        """Send no further command and read no more; wait for the thread."""
        self._halt.set()
        if self._thread is not None:
            self._thread.join(2.0)
