"""The rubbing protocol: ``move p2`` / ``move p1`` commands on a fixed schedule.

As in the rubbing-lab measurements: the fingers start closed at ``p1``; motion
``k`` sends ``move p2`` at ``start_s + 2 k dwell_s`` and ``move p1`` one
``dwell_s`` later; the recording ends ``dwell_s`` after the last command. Each
command is written as an event ``{"t": ..., "kind": "move", "target": "p2"}``
(plus the commanded ``position``) at the recording time it was sent; a command
the actuator refuses ends the protocol with a ``protocol_error`` event.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from frictionfit.acquisition.actuator import Actuator
from frictionfit.acquisition.recorder import RecordingWriter
from frictionfit.recording import Event

__all__ = ["ProtocolRunner", "RubbingProtocol"]


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


class ProtocolRunner:
    """Sends the protocol's commands on time from its own thread, logging each as an event.

    Timing does not depend on the recording loop (disk flushes can take tens of ms):
    the thread sleeps until each command is due on the recording clock.
    """

    def __init__(self, protocol: RubbingProtocol, actuator: Actuator,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.protocol, self.actuator, self.clock = protocol, actuator, clock
        self.error: str | None = None
        self._halt = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, t0: float, writer: RecordingWriter) -> Callable[[], None]:
        """Run the schedule against the recording clock ``clock() - t0`` (s); return a stop."""
        self._thread = threading.Thread(target=self._run, args=(t0, writer),
                                        name="rubbing protocol", daemon=True)
        self._thread.start()
        return self.stop

    def _run(self, t0: float, writer: RecordingWriter) -> None:
        for t_cmd, target in self.protocol.schedule():
            if self._halt.wait(max(t_cmd - (self.clock() - t0), 0.0)):
                return
            position = self.protocol.p2 if target == "p2" else self.protocol.p1
            t = self.clock() - t0
            try:
                self.actuator.move_to(position)
            except Exception as exc:  # kept as an event in the sidecar; the recording goes on
                self.error = f"move {target} at t={t:.3f} s failed: {exc}"
                writer.add_event(Event(round(t, 6), "protocol_error", target,
                                       {"detail": str(exc)}))
                return
            writer.add_event(Event(round(t, 6), "move", target, {"position": position}))

    def stop(self) -> None:
        """Send no further command; wait for the thread."""
        self._halt.set()
        if self._thread is not None:
            self._thread.join(2.0)
