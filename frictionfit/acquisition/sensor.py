"""An OptoForce DAQ on a pyserial port: handshake, counts to newtons, a reader thread.

The port is opened with :func:`serial.serial_for_url`, so a device path, a pty,
``loop://`` and ``socket://host:port`` all work. The start-up handshake follows
section 9 of the team's ``reference/optoforce-serial-protocol.md``: flush, ask for
the serial number, send the configuration (rate, filter, zero) and check its
acknowledge, skipping the data frames the DAQ streams meanwhile.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from frictionfit._optional import lazy_module
from frictionfit.acquisition.frames import (
    FILTER_CUTOFF_HZ,
    SPEED_CODES,
    ConfigAck,
    ConfigCommand,
    DataFrame,
    FrameParser,
    Message,
    SerialReply,
    SerialRequest,
)
from frictionfit.errors import AcquisitionError

serial = lazy_module("serial", "The OptoForce sensor")

__all__ = ["OptoForceSensor", "load_sensitivity"]

BAUD = 1_000_000
#: How long (s) to wait for an acknowledge or a serial-number reply (reference section 7).
REPLY_TIMEOUT_S = 0.5


def load_sensitivity(path: str | Path, serial_number: str) -> tuple[float, ...]:
    """Per-axis sensitivity (counts per N, or per N m for torques) of one sensor.

    The file is JSON mapping serial numbers to lists of counts-per-unit, one per
    axis, as read from each sensor's calibration sheet, e.g.
    ``{"ISE0A129": [400.9, 400.9, 400.9]}``.
    """
    path = Path(path)
    try:
        table = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise AcquisitionError(f"{path}: cannot read the sensitivity file: {exc}") from None
    if serial_number not in table:
        raise AcquisitionError(
            f"{path}: no sensitivity for sensor {serial_number!r}; "
            f"the file lists {sorted(table)}")
    values = tuple(float(v) for v in table[serial_number])
    if not values or any(v <= 0 for v in values):
        raise AcquisitionError(
            f"{path}: sensitivity of {serial_number!r} must be positive counts per unit, "
            f"got {list(values)}")
    return values


def speed_code(rate_hz: float) -> int:
    """The DAQ's speed code for a nominal output rate (1000, 333, 100, 30 or 10 Hz)."""
    code = SPEED_CODES.get(int(round(rate_hz)))
    if code is None:
        raise AcquisitionError(
            f"rate {rate_hz:g} Hz is not one the DAQ offers; choose one of {sorted(SPEED_CODES)}")
    return code


class OptoForceSensor:
    """One OptoForce DAQ: open, handshake, then frames from a background thread.

    Parameters
    ----------
    url : str
        Anything :func:`serial.serial_for_url` opens (``/dev/ttyACM0``, ``loop://``,
        ``socket://host:port``).
    queue_size : int
        Capacity of the frame queue; frames that find it full are dropped and
        counted in ``frames_overflow`` (1 minute at 1 kHz by default).

    Attributes
    ----------
    serial_number : str or None
        As the DAQ answered, once :meth:`query_serial` succeeded.
    error : str or None
        Why the reader thread stopped (e.g. the cable was pulled), else None.
    first_frame_time : float or None
        ``time.monotonic()`` when the first data frame after :meth:`start` arrived.

    Examples
    --------
    >>> sensor = OptoForceSensor("loop://")
    >>> from frictionfit.acquisition.frames import ConfigAck
    >>> sensor.open()
    >>> _ = sensor.port.write(ConfigAck(0).encode())  # loop:// answers for the DAQ
    >>> sensor.configure(1000)
    9
    >>> sensor.close()
    """

    def __init__(self, url: str, *, queue_size: int = 60_000) -> None:
        self.url = url
        self.port: serial.SerialBase | None = None
        self.parser = FrameParser()
        self.serial_number: str | None = None
        self.error: str | None = None
        self.first_frame_time: float | None = None
        self.frames_overflow = 0
        self.frames_before_config = 0
        self._carry = 0  # samples dropped on a full queue, added to the next frame's lost_before
        self._queue: queue.Queue[tuple[float, DataFrame]] = queue.Queue(queue_size)
        self._backlog: list[Message] = []
        self._thread: threading.Thread | None = None
        self._halt = threading.Event()
        self._ack_seen = threading.Event()

    def open(self) -> None:
        """Open the port (1 000 000 baud, 8N1) and drop whatever it had buffered."""
        try:
            self.port = serial.serial_for_url(self.url, baudrate=BAUD, timeout=0.01)
            self.port.reset_input_buffer()
        except (serial.SerialException, OSError, ValueError) as exc:
            raise AcquisitionError(f"{self.url}: cannot open the port: {exc}") from None
        self.parser = FrameParser()
        self._backlog: list[Message] = []
        self.error = None

    def _await(self, kind: type[Message], what: str) -> Message:
        assert self.port is not None, "open() first"
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        chunk = b""
        while time.monotonic() < deadline:
            self._backlog += self.parser.feed(chunk)
            while self._backlog:
                msg = self._backlog.pop(0)
                if isinstance(msg, kind):
                    return msg
                self.frames_before_config += isinstance(msg, DataFrame)
            try:
                chunk = self.port.read(max(1, self.port.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise AcquisitionError(f"{self.url}: link lost waiting for {what}: {exc}") from None
        raise AcquisitionError(
            f"{self.url}: no {what} within {REPLY_TIMEOUT_S} s (is this an OptoForce DAQ, "
            "and is no other program reading the port?)")

    def _send(self, data: bytes) -> None:
        assert self.port is not None, "open() first"
        try:
            self.port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise AcquisitionError(f"{self.url}: cannot write to the port: {exc}") from None

    def query_serial(self, retries: int = 1) -> str | None:
        """Ask for the serial number (retried once); None when the DAQ never answers."""
        for _ in range(retries + 1):
            self._send(SerialRequest().encode())
            try:
                reply = self._await(SerialReply, "serial-number reply")
            except AcquisitionError:
                continue
            self.serial_number = reply.serial
            return reply.serial
        return None

    def configure(self, rate_hz: float, filter_code: int = 0, zero: bool = False) -> int:
        """Send rate (Hz), filter code and zeroing; check the acknowledge; return bytes sent.

        Zeroing sends the configuration with zero = 0 and then with 255 (a second
        255 alone does not re-zero), each acknowledged, as the reference says.
        """
        if filter_code not in FILTER_CUTOFF_HZ:
            raise AcquisitionError(f"filter code {filter_code} unknown; choose one of "
                                   f"{FILTER_CUTOFF_HZ} (code: cut-off in Hz)")
        code = speed_code(rate_hz)
        sent = 0
        for zero_byte in ((0, 255) if zero else (0,)):
            cmd = ConfigCommand(code, filter_code, zero_byte).encode()
            self._send(cmd)
            sent += len(cmd)
            ack = self._await(ConfigAck, "configuration acknowledge")
            if ack.result != 0:
                raise AcquisitionError(f"{self.url}: the DAQ rejected the configuration "
                                       f"(speed {code}, filter {filter_code}): result {ack.result}")
        return sent

    def reconfigure(self, rate_hz: float, filter_code: int = 0) -> None:
        """Send rate (Hz) and filter code again while the reader thread runs, and wait for
        the acknowledge (the reader sees it); no zeroing (a hardware zero taken now would
        tare a loaded sensor). AcquisitionError without an acknowledge."""
        if not self._acknowledged(ConfigCommand(speed_code(rate_hz), filter_code, 0)):
            raise AcquisitionError(f"{self.url}: no configuration acknowledge within "
                                   f"{REPLY_TIMEOUT_S} s")

    def _acknowledged(self, command: ConfigCommand) -> bool:
        """Send ``command`` while the reader thread runs; whether the reader saw an
        acknowledge after it within :data:`REPLY_TIMEOUT_S` (an earlier one does not count)."""
        self._ack_seen.clear()
        self._send(command.encode())
        return self._ack_seen.wait(REPLY_TIMEOUT_S)

    def start(self) -> None:
        """Start reading frames into the queue in a background thread."""
        self._halt.clear()
        self._ack_seen.clear()
        self._thread = threading.Thread(target=self._run, name=f"optoforce {self.url}",
                                        daemon=True)
        self._thread.start()

    def _run(self) -> None:
        port = self.port
        assert port is not None, "open() first"
        self._queue_messages(self._backlog)  # frames that came with the acknowledge
        self._backlog = []
        try:
            while not self._halt.is_set():
                try:
                    chunk = port.read(max(1, port.in_waiting))
                except Exception as exc:  # any failure of the link ends this thread, reported
                    self.error = f"{type(exc).__name__}: {exc}"
                    return
                self._queue_messages(self.parser.feed(chunk))
        finally:
            self._queue_messages(self.parser.flush())  # a frame held back for its successor

    def _queue_messages(self, msgs: list[Message]) -> None:
        """Queue the data frames of ``msgs``; note an acknowledge. A frame that finds the
        queue full is counted, and its sample added to the next frame's ``lost_before``."""
        now = time.monotonic()
        for msg in msgs:
            if isinstance(msg, ConfigAck):
                self._ack_seen.set()
            elif isinstance(msg, DataFrame):
                if self.first_frame_time is None:
                    self.first_frame_time = now
                if self._carry:
                    msg = replace(msg, lost_before=msg.lost_before + self._carry)
                try:
                    self._queue.put_nowait((now, msg))
                    self._carry = 0
                except queue.Full:
                    self.frames_overflow += 1
                    self._carry = msg.lost_before + 1

    @property
    def alive(self) -> bool:
        """True while the reader thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def received(self) -> list[tuple[float, DataFrame]]:
        """Every frame queued so far with the host time it arrived (``time.monotonic()``,
        s), oldest first (non-blocking)."""
        out = []
        while True:
            try:
                out.append(self._queue.get_nowait())
            except queue.Empty:
                return out

    def frames(self) -> list[DataFrame]:
        """Every frame queued so far, oldest first (non-blocking)."""
        return [frame for _, frame in self.received()]

    def stop(self, filter_code: int = 0) -> None:
        """Ask the DAQ to stop streaming, read until its acknowledge, stop the thread.

        Every frame sent before the acknowledge is still queued, so nothing the DAQ
        sent is lost at the end of a recording.
        """
        if self.alive:
            try:
                self._acknowledged(ConfigCommand(0, filter_code, 0))
            except AcquisitionError as exc:
                self.error = str(exc)
        self._halt.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def close(self) -> None:
        """Stop the thread and close the port (safe to call twice)."""
        self._halt.set()
        if self._thread is not None:
            self._thread.join(2.0)
        if self.port is not None:
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass
            self.port = None

    def counts_per_unit(self, path: str | Path | None, n_counts: int) -> Sequence[float] | None:
        """Sensitivities for this sensor from ``path`` (None: keep raw counts)."""
        if path is None:
            return None
        if self.serial_number is None:
            raise AcquisitionError(f"{self.url}: the DAQ did not tell its serial number, so "
                                   f"no sensitivity can be picked from {path}")
        sens = load_sensitivity(path, self.serial_number)
        if len(sens) not in (1, n_counts):
            raise AcquisitionError(f"{path}: {self.serial_number!r} has {len(sens)} "
                                   f"sensitivities but the DAQ sends {n_counts} axes")
        return sens * n_counts if len(sens) == 1 else sens
