"""A fake OptoForce DAQ on a pty pair, for tests without hardware.

It answers the serial-number request and the configuration (with an
acknowledge), streams 1-channel data frames at the configured rate (100 Hz from
power-up, like the real DAQ), corrupts every ``corrupt_every``-th frame on
purpose (one flipped force bit: a checksum failure), slips garbage between
frames, and can be unplugged (:meth:`disconnect`) and plugged back
(:meth:`reconnect`) under the same path, a symlink as udev would make.

Its counters say exactly what it sent after the configuration was acknowledged:
``frames_sent`` (every frame fully written, corrupted ones included) and
``frames_corrupted``.
"""

from __future__ import annotations

import errno
import os
import pty
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np

from frictionfit.acquisition.frames import (
    ConfigAck,
    ConfigCommand,
    DataFrame,
    FrameParser,
    SerialReply,
    SerialRequest,
)

#: Bytes the fake keeps queued for a reader that does not read, before it drops frames.
MAX_PENDING = 1 << 16


def noisy_counts(seed: int = 0) -> Callable[[int], tuple[int, ...]]:
    """A default source: slow sines plus Gaussian noise of 3 counts, frame ``k`` -> counts."""
    rng = np.random.default_rng(seed)

    def source(k: int) -> tuple[int, ...]:
        base = 400 * np.sin(2 * np.pi * k / np.array([1000.0, 1700.0, 2300.0]))
        return tuple(int(v) for v in np.round(base + rng.normal(0, 3, 3)))

    return source


class FakeOptoForce:
    """A fake 1-channel DAQ at ``path`` (a symlink to the current pty).

    Parameters
    ----------
    path : Path
        Where the port appears (use it as the sensor URL).
    source : callable, optional
        Frame index after the configuration (0, 1, ...) -> three int16 counts.
    corrupt_every : int
        Corrupt every n-th configured frame (0: never).
    garbage_every : int
        Put 1-20 garbage bytes (never a start byte) before every n-th frame (0: never).
    rate_error : float
        Relative error of the DAQ's clock (0.01: its frames come 1 % faster than the
        configured rate, by the host's clock).
    status : callable, optional
        Frame index after the configuration -> the frame's status word (default 0).
    reply_delay_s : float
        How long a configuration takes to act and be acknowledged (s); the DAQ streams on
        as before meanwhile.
    """

    def __init__(self, path: Path, *, serial: str = "ISE0A129",
                 source: Callable[[int], tuple[int, ...]] | None = None,
                 corrupt_every: int = 0, garbage_every: int = 0, seed: int = 0,
                 rate_error: float = 0.0, status: Callable[[int], int] | None = None,
                 reply_delay_s: float = 0.0) -> None:
        self.rate_error = rate_error
        self.reply_delay_s = reply_delay_s
        self._due: list[tuple[float, ConfigCommand]] = []  # configurations not yet acted on
        self.status = status or (lambda k: 0)
        self.path = Path(path)
        self.serial = serial
        self.source = source or noisy_counts(seed)
        self.corrupt_every, self.garbage_every = corrupt_every, garbage_every
        self.rng = np.random.default_rng(seed + 1)
        self.frames_sent = 0
        self.frames_corrupted = 0
        self.frames_unsent = 0
        self.k = -1
        self.configs: list[ConfigCommand] = []
        self._lock = threading.Lock()
        self._halt = threading.Event()
        self._out: deque[tuple[bytes, str]] = deque()
        self._pending_bytes = 0
        self._fds: tuple[int, int] | None = None
        self._thread: threading.Thread | None = None

    # -- plugging ---------------------------------------------------------------
    def _plug(self) -> None:
        master, slave = pty.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        tmp = self.path.with_name(self.path.name + ".new")
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.path)
        self._parser = FrameParser("host")
        self._speed, self._counter, self._configured = 10, 0, False
        self._t_stream, self._emitted = time.monotonic(), 0
        self._fds = (master, slave)

    def disconnect(self) -> None:
        """Pull the cable: the pty disappears; whatever was not yet written is lost."""
        with self._lock:
            if self._fds is None:
                return
            self.path.unlink(missing_ok=True)
            for fd in self._fds:
                os.close(fd)
            self._fds = None
            self.frames_unsent += sum(1 for _, kind in self._out if kind != "other")
            self._out.clear()
            self._pending_bytes = 0

    def reconnect(self) -> None:
        """Plug the cable back: a new pty at the same path, streaming at power-up rate."""
        with self._lock:
            self._plug()

    def pause(self, seconds: float) -> None:
        """Send nothing for ``seconds``, the counter standing still (blocks that long)."""
        with self._lock:
            speed, self._speed = self._speed, 0
        time.sleep(seconds)
        with self._lock:
            self._speed, self._t_stream, self._emitted = speed, time.monotonic(), 0

    def power_cycle(self) -> None:
        """Restart the DAQ with the USB link up (a brown-out): counter 0, streaming at its
        power-up rate (100 Hz) until configured again."""
        with self._lock:
            self._speed, self._counter, self._configured = 10, 0, False
            self._t_stream, self._emitted = time.monotonic(), 0

    def set_counter(self, counter: int) -> None:
        """Jump the sample counter to ``counter``, as a DAQ that restarted would."""
        with self._lock:
            self._counter = counter & 0xFFFF

    def __enter__(self) -> FakeOptoForce:
        self._plug()
        self._thread = threading.Thread(target=self._run, name="fake optoforce", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._halt.set()
        if self._thread is not None:
            self._thread.join(5)
        self.disconnect()

    # -- the DAQ ----------------------------------------------------------------
    def _answer(self, data: bytes) -> None:
        for msg in self._parser.feed(data):
            if isinstance(msg, SerialRequest):
                self._queue(SerialReply(self.serial).encode(), "other")
            elif isinstance(msg, ConfigCommand):
                self.configs.append(msg)
                self._due.append((time.monotonic() + self.reply_delay_s, msg))

    def _act(self) -> None:
        """Act on, and acknowledge, each configuration whose time has come."""
        while self._due and self._due[0][0] <= time.monotonic():
            _, msg = self._due.pop(0)
            self._queue(ConfigAck(0).encode(), "other")
            self._speed, self._configured = msg.speed, msg.speed > 0
            self._t_stream, self._emitted = time.monotonic(), 0

    def _emit(self) -> None:
        if self._speed == 0:
            return
        due = int((time.monotonic() - self._t_stream) * 1000.0 / self._speed
                  * (1 + self.rate_error))
        while self._emitted < due:
            self._emitted += 1
            self._counter = (self._counter + self._speed) & 0xFFFF
            if self._pending_bytes > MAX_PENDING:
                self.frames_unsent += self._configured
                continue
            kind, counts, status = "boot", (0, 0, 0), 0
            if self._configured:
                self.k += 1
                counts, status = self.source(self.k), self.status(self.k)
                kind = "data"
            raw = bytearray(DataFrame(self._counter, status, counts).encode())
            n = self.corrupt_every
            if kind == "data" and n and self.k % n == n - 1:
                raw[9] ^= 0x01
                kind = "corrupt"
            if self.garbage_every and self._emitted % self.garbage_every == 0:
                junk = self.rng.integers(0, 0xAA, self.rng.integers(1, 21), dtype=np.uint8)
                self._queue(junk.tobytes(), "other")
            self._queue(bytes(raw), kind)

    def _queue(self, data: bytes, kind: str) -> None:
        self._out.append((data, kind))
        self._pending_bytes += len(data)

    def _write(self, master: int) -> None:
        while self._out:
            data, kind = self._out[0]
            try:
                n = os.write(master, data)
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno == errno.EIO:
                    return
                raise
            self._pending_bytes -= n
            if n < len(data):
                self._out[0] = (data[n:], kind)
                return
            self._out.popleft()
            if kind in ("data", "corrupt"):
                self.frames_sent += 1
                self.frames_corrupted += kind == "corrupt"

    def _run(self) -> None:
        while not self._halt.is_set():
            with self._lock:
                if self._fds is not None:
                    master = self._fds[0]
                    try:
                        self._answer(os.read(master, 4096))
                    except OSError:
                        pass  # nothing to read yet (EAGAIN) or no reader (EIO)
                    self._emit()
                    self._act()
                    self._write(master)
            time.sleep(0.001)
