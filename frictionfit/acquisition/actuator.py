"""The gripper's finger: an :class:`Actuator` interface, a simulated one, a Dynamixel servo.

Positions are in the actuator's own unit: encoder counts for a Dynamixel
(4096 per turn, 0.088 degrees each), any unit for the simulated gripper.
"""

from __future__ import annotations

import abc
import struct
import time
from collections.abc import Callable

import numpy as np
import serial

from frictionfit.acquisition.dynamixel import PING, READ, STATUS, WRITE, Packet, PacketParser
from frictionfit.errors import AcquisitionError

__all__ = ["Actuator", "DynamixelActuator", "SimulatedGripper"]


class Actuator(abc.ABC):
    """What the rubbing protocol needs from a finger drive.

    ``counts_per_revolution`` is the encoder's resolution when the positions are
    encoder counts of a rotary drive, None otherwise. ``position_timeout_s`` is the
    longest :meth:`position` waits for the hardware (0 when it does not wait).
    """

    counts_per_revolution: int | None = None
    position_timeout_s: float = 0.0

    @abc.abstractmethod
    def move_to(self, position: float) -> None:
        """Command a move to ``position`` (returns at once; the move takes its time)."""

    @abc.abstractmethod
    def position(self) -> float:
        """The present position."""

    def close(self) -> None:  # noqa: B027 - optional for actuators holding nothing
        """Release the hardware (nothing to do by default)."""


class SimulatedGripper(Actuator):
    """A finger that starts moving ``latency_s`` after a command and arrives ``move_s`` later.

    The path is a raised-cosine ramp, the shape of the contact models' drive
    (:func:`frictionfit.models.stick_slip.drive`), so a simulator fed with
    :meth:`trajectory` sees the motion the commands asked for.

    Examples
    --------
    >>> clock = iter([0.0, 0.0, 1.0]).__next__
    >>> g = SimulatedGripper(0.0, clock=clock)
    >>> g.move_to(10.0)
    >>> g.position()
    10.0
    """

    def __init__(self, position: float = 0.0, *, move_s: float = 0.12, latency_s: float = 0.02,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.move_s, self.latency_s, self.clock = move_s, latency_s, clock
        self.t_start = clock()
        self.commands: list[tuple[float, float]] = [(-np.inf, float(position))]

    def move_to(self, position: float) -> None:
        self.commands.append((self.clock() - self.t_start, float(position)))

    def trajectory(self, t: np.ndarray) -> np.ndarray:
        """Positions at times ``t`` (s since the gripper was made) for the commands so far.

        A command given while a move is under way starts from where the finger is.
        """
        t = np.asarray(t, dtype=np.float64)
        x = np.full(t.shape, self.commands[0][1])
        for t_cmd, target in self.commands[1:]:
            u = np.clip((t - t_cmd - self.latency_s) / self.move_s, 0.0, 1.0)
            x = np.where(t >= t_cmd, x + (target - x) * (0.5 - 0.5 * np.cos(np.pi * u)), x)
        return x

    def position(self) -> float:
        return float(self.trajectory(np.array(self.clock() - self.t_start)))


#: Control-table addresses of the X series (reference section 7).
TORQUE_ENABLE, GOAL_POSITION, PRESENT_POSITION = 64, 116, 132
_ERRORS = {1: "result fail", 2: "instruction error", 3: "CRC error", 4: "data range error",
           5: "data length error", 6: "data limit error", 7: "access error"}


class DynamixelActuator(Actuator):
    """A Dynamixel X-series servo in position mode over Protocol 2.0.

    Parameters
    ----------
    url : str
        The port (``/dev/ttyUSB0`` for a U2D2, ``loop://`` in tests).
    servo_id : int
        The servo's ID (factory 1).
    baudrate : int
        Factory 57 600.
    limits : (int, int)
        Allowed goal positions in counts (Min/Max Position Limit; 0-4095 by default).
    timeout_s : float
        How long to wait for a status packet.
    position_timeout_s : float
        How long :meth:`position` waits for its reply: short, because the protocol
        reads the position between commands and starts no read closer than this to a
        command. The DynamixelSDK waits about 35 ms for a short reply at 57 600 baud
        with the adapter's default 16 ms latency.
    """

    counts_per_revolution = 4096

    def __init__(self, url: str, servo_id: int = 1, *, baudrate: int = 57_600,
                 limits: tuple[int, int] = (0, 4095), timeout_s: float = 0.5,
                 position_timeout_s: float = 0.05) -> None:
        self.url, self.servo_id, self.limits, self.timeout_s = url, servo_id, limits, timeout_s
        self.position_timeout_s = position_timeout_s
        try:
            self.port = serial.serial_for_url(url, baudrate=baudrate, timeout=0.005)
            self.port.reset_input_buffer()
        except (serial.SerialException, OSError, ValueError) as exc:
            raise AcquisitionError(f"{url}: cannot open the servo's port: {exc}") from None
        self.parser = PacketParser()

    def _exchange(self, instruction: int, params: bytes, what: str,
                  timeout_s: float | None = None) -> bytes:
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        try:
            # The servo speaks only when asked, so what waits now is a late reply to an
            # earlier request; kept, it would pass for this one's and shift every later one.
            self.port.reset_input_buffer()
            self.parser.clear()
            self.port.write(Packet(self.servo_id, instruction, params).encode())
        except (serial.SerialException, OSError) as exc:
            raise AcquisitionError(f"{self.url}: cannot write to the servo: {exc}") from None
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            chunk = self.port.read(max(1, self.port.in_waiting))
            for pkt in self.parser.feed(chunk):
                if pkt.instruction != STATUS or pkt.id != self.servo_id:
                    continue  # our own echo on a half-duplex adapter, or another servo
                if pkt.error:
                    alert = " (alert: hardware error latched; read address 70, reboot)" if (
                        pkt.error & 0x80) else ""
                    number = pkt.error & 0x7F
                    raise AcquisitionError(
                        f"{self.url}: servo {self.servo_id} refused {what}: error {number} "
                        f"({_ERRORS.get(number, 'unknown')}){alert}")
                return pkt.data
        raise AcquisitionError(f"{self.url}: no status from servo {self.servo_id} for {what} "
                               f"within {timeout_s} s (wrong ID, baud rate or protocol?)")

    def ping(self) -> int:
        """The model number (e.g. 1020 for an XM430-W350)."""
        return struct.unpack("<H", self._exchange(PING, b"", "PING")[:2])[0]

    def write(self, address: int, value: int, size: int) -> None:
        """Write a ``size``-byte signed value at a control-table ``address``."""
        fmt = {1: "<b", 2: "<h", 4: "<i"}[size]
        self._exchange(WRITE, struct.pack("<H", address) + struct.pack(fmt, value),
                       f"WRITE {value} at {address}")

    def enable(self) -> None:
        """Switch the torque on (the servo holds and moves)."""
        self.write(TORQUE_ENABLE, 1, 1)

    def move_to(self, position: float) -> None:
        lo, hi = self.limits
        goal = int(round(position))
        if not lo <= goal <= hi:
            raise AcquisitionError(f"{self.url}: goal position {goal} is outside the servo's "
                                   f"limits {lo}..{hi} counts")
        self.write(GOAL_POSITION, goal, 4)

    def position(self) -> float:
        data = self._exchange(READ, struct.pack("<HH", PRESENT_POSITION, 4), "READ position",
                              self.position_timeout_s)
        if len(data) != 4:
            raise AcquisitionError(f"{self.url}: position reply has {len(data)} bytes, not 4")
        return float(struct.unpack("<i", data)[0])

    def close(self) -> None:
        self.port.close()
