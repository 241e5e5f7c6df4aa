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

from frictionfit._optional import lazy_module
from frictionfit.acquisition.dynamixel import PING, READ, STATUS, WRITE, Packet, PacketParser
from frictionfit.errors import AcquisitionError

serial = lazy_module("serial", "The Dynamixel actuator")

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

    def check(self, position: float) -> None:  # noqa: B027 - any position by default
        """Raise :class:`~frictionfit.errors.AcquisitionError` for a position the drive
        cannot be sent to, before anything moves."""

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
OPERATING_MODE, MAX_POSITION_LIMIT, MIN_POSITION_LIMIT = 11, 48, 52
TORQUE_ENABLE, HARDWARE_ERROR_STATUS, GOAL_POSITION, PRESENT_POSITION = 64, 70, 116, 132
_ITEMS = {OPERATING_MODE: "operating mode", MAX_POSITION_LIMIT: "max position limit",
          MIN_POSITION_LIMIT: "min position limit", HARDWARE_ERROR_STATUS: "hardware error status",
          PRESENT_POSITION: "position"}
_FORMATS = {1: "<B", 2: "<h", 4: "<i"}
_ERRORS = {1: "result fail", 2: "instruction error", 3: "CRC error", 4: "data range error",
           5: "data length error", 6: "data limit error", 7: "access error"}
#: Hardware Error Status bits (reference section 6).
_HARDWARE_ERRORS = {0: "input voltage", 2: "overheating", 3: "motor encoder",
                    4: "electrical shock", 5: "overload"}
#: Operating modes that follow Goal Position, with their range of goals in counts (reference
#: section 8): 3 between the servo's own position limits, 4 and 5 over +-256 turns.
_POSITION_MODES = {3: "position", 4: "extended position", 5: "current-based position"}
_OTHER_MODES = {0: "current", 1: "velocity", 16: "PWM"}
EXTENDED_RANGE = (-1_048_575, 1_048_575)


class DynamixelActuator(Actuator):
    """A Dynamixel X-series servo in a position mode over Protocol 2.0.

    Parameters
    ----------
    url : str
        The port (``/dev/ttyUSB0`` for a U2D2, ``loop://`` in tests).
    servo_id : int
        The servo's ID (factory 1).
    baudrate : int
        Factory 57 600.
    limits : (int, int), optional
        Allowed goal positions in counts. Without them, :meth:`prepare` reads them from
        the servo: its Min/Max Position Limit in position mode (3), +-256 turns in
        extended (4) and current-based (5) position mode.
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
                 limits: tuple[int, int] | None = None, timeout_s: float = 0.5,
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
                  timeout_s: float | None = None, alert_ok: bool = False) -> bytes:
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
                number = pkt.error & 0x7F
                if number:
                    raise AcquisitionError(
                        f"{self.url}: servo {self.servo_id} refused {what}: error {number} "
                        f"({_ERRORS.get(number, 'unknown')})" + (
                            f"; {self._hardware_error()}" if pkt.error & 0x80 else ""))
                if pkt.error & 0x80 and not alert_ok:
                    raise AcquisitionError(f"{self.url}: servo {self.servo_id} cannot "
                                           f"{what}: {self._hardware_error()}")
                return pkt.data
        raise AcquisitionError(f"{self.url}: no status from servo {self.servo_id} for {what} "
                               f"within {timeout_s} s (wrong ID, baud rate or protocol?)")

    def _hardware_error(self) -> str:
        """The latched hardware error (the alert bit of a status), in words."""
        try:
            bits = self.read(HARDWARE_ERROR_STATUS, 1, alert_ok=True)
        except AcquisitionError as exc:
            return f"a hardware error is latched (alert), and reading which failed: {exc}"
        names = [name for bit, name in _HARDWARE_ERRORS.items() if bits & (1 << bit)] or [
            f"unknown bits 0x{bits:02X}"]
        return (f"hardware error {', '.join(names)} (address {HARDWARE_ERROR_STATUS} = "
                f"0x{bits:02X}); the servo may have switched its torque off until it is "
                "rebooted or power-cycled")

    def ping(self) -> int:
        """The model number (e.g. 1020 for an XM430-W350)."""
        return struct.unpack("<H", self._exchange(PING, b"", "PING")[:2])[0]

    def read(self, address: int, size: int, timeout_s: float | None = None,
             alert_ok: bool = False) -> int:
        """Read the ``size``-byte value at a control-table ``address`` (1-byte items are
        unsigned, 2- and 4-byte ones signed, as in the X series' table)."""
        what = f"READ {_ITEMS.get(address, address)}"
        data = self._exchange(READ, struct.pack("<HH", address, size), what, timeout_s,
                              alert_ok)
        if len(data) != size:
            raise AcquisitionError(f"{self.url}: {what} replied {len(data)} bytes, not {size}")
        return struct.unpack(_FORMATS[size], data)[0]

    def write(self, address: int, value: int, size: int) -> None:
        """Write a ``size``-byte value at a control-table ``address`` (signs as :meth:`read`)."""
        self._exchange(WRITE, struct.pack("<H", address) + struct.pack(_FORMATS[size], value),
                       f"WRITE {value} at {address}")

    def prepare(self) -> int:
        """Ping, check that the servo follows goal positions, learn its limits (unless
        given), switch the torque on; return the model number."""
        model = self.ping()
        mode = self.read(OPERATING_MODE, 1)
        if mode not in _POSITION_MODES:
            raise AcquisitionError(
                f"{self.url}: servo {self.servo_id} is in {_OTHER_MODES.get(mode, 'unknown')} "
                f"control (Operating Mode {mode}), where it ignores goal positions; set mode "
                f"3, 4 or 5 ({', '.join(_POSITION_MODES.values())})")
        if self.limits is None:
            self.limits = (self.read(MIN_POSITION_LIMIT, 4), self.read(MAX_POSITION_LIMIT, 4)
                           ) if mode == 3 else EXTENDED_RANGE
        self.write(TORQUE_ENABLE, 1, 1)
        return model

    def check(self, position: float) -> None:
        lo, hi = self.limits if self.limits is not None else EXTENDED_RANGE
        goal = int(round(position))
        if not lo <= goal <= hi:
            raise AcquisitionError(f"{self.url}: goal position {goal} is outside servo "
                                   f"{self.servo_id}'s limits {lo}..{hi} counts")

    def move_to(self, position: float) -> None:
        self.check(position)
        self.write(GOAL_POSITION, int(round(position)), 4)

    def position(self) -> float:
        return float(self.read(PRESENT_POSITION, 4, self.position_timeout_s))

    def close(self) -> None:
        self.port.close()
