"""The rubbing protocol: ``move p2`` / ``move p1`` commands on a fixed schedule.

As in the rubbing-lab measurements: the fingers start closed at ``p1``; motion
``k`` sends ``move p2`` at ``start_s + 2 k dwell_s`` and ``move p1`` one
``dwell_s`` later; the recording ends ``dwell_s`` after the last command. Each
command is written as an event ``{"t": ..., "kind": "move", "target": "p2"}``
(plus the commanded ``position``) at the recording time it was sent.
"""

from __future__ import annotations

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
    """Sends the protocol's commands when their time comes; use as ``record(on_tick=...)``."""

    def __init__(self, protocol: RubbingProtocol, actuator: Actuator) -> None:
        self.protocol, self.actuator = protocol, actuator
        self.pending = protocol.schedule()

    def __call__(self, t: float, writer: RecordingWriter) -> None:
        """At recording time ``t`` (s), send every command now due and log it."""
        while self.pending and self.pending[0][0] <= t:
            _, target = self.pending.pop(0)
            position = self.protocol.p2 if target == "p2" else self.protocol.p1
            self.actuator.move_to(position)
            writer.add_event(Event(round(t, 6), "move", target, {"position": position}))
