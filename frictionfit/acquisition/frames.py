"""OptoForce DAQ messages as bytes and back: a pure codec, no I/O.

Every message is ``header (4 bytes) + payload + checksum (2 bytes, big-endian)``,
the checksum being the plain 16-bit sum of every byte before it (see the team's
``reference/optoforce-serial-protocol.md``, sections 2-8). :class:`FrameParser`
is fed bytes in chunks of any size and returns whole messages; it resynchronises
on the header after garbage or a partial frame, counts checksum failures and
discarded bytes, and tracks the sample counter to count lost samples.

Examples
--------
>>> parser = FrameParser()
>>> msgs = parser.feed(bytes.fromhex("AA0708 0A 2D6A 0000 FFF7 FFFB 0007 0551"))
>>> msgs[0].counter, msgs[0].counts
(11626, (-9, -5, 7))
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

__all__ = [
    "DAQ_TO_HOST",
    "HOST_TO_DAQ",
    "FILTER_CUTOFF_HZ",
    "SPEED_CODES",
    "ConfigAck",
    "ConfigCommand",
    "DataFrame",
    "FrameParser",
    "Message",
    "SerialReply",
    "SerialRequest",
    "axis_names",
    "checksum",
]

_DATA = {3: b"\xaa\x07\x08\x0a", 12: b"\xaa\x07\x08\x1c", 6: b"\xaa\x07\x08\x10"}
_ACK = b"\xaa\x00\x50\x01"
_SERIAL_REPLY = b"\xaa\x00\x12\x08"
_CONFIG = b"\xaa\x00\x32\x03"
_SERIAL_REQUEST = b"\xab\x00\x12\x08"

#: Output rate (Hz, nominal) -> speed code; rate = 1000 / code (reference section 6.1).
SPEED_CODES = {1000: 1, 333: 3, 100: 10, 30: 33, 10: 100}
#: Filter code -> low-pass cut-off in Hz (0 = no filter; reference section 6.2).
FILTER_CUTOFF_HZ = {0: None, 1: 500.0, 2: 150.0, 3: 50.0, 4: 15.0, 5: 5.0, 6: 1.5}
_AXES = {3: ("x", "y", "z"), 6: ("x", "y", "z", "tx", "ty", "tz")}


def checksum(data: bytes) -> int:
    """The OptoForce checksum: sum of ``data`` modulo 65536."""
    return sum(data) & 0xFFFF


def _seal(body: bytes) -> bytes:
    return body + struct.pack(">H", checksum(body))


@dataclass(frozen=True)
class DataFrame:
    """One data frame: sample ``counter`` (uint16), ``status`` word and force ``counts``.

    ``counts`` holds 3 values (1-channel DAQ: Fx, Fy, Fz), 12 (4-channel DAQ,
    channel-major) or 6 (6-axis DAQ: Fx, Fy, Fz, Tx, Ty, Tz), in raw int16 counts.
    ``lost_before`` is set by the parser: samples the counter says are missing
    between the previous valid frame and this one.
    """

    counter: int
    status: int
    counts: tuple[int, ...]
    lost_before: int = 0

    def __post_init__(self) -> None:
        if len(self.counts) not in _DATA:
            raise ValueError(f"a data frame carries 3, 6 or 12 counts, not {len(self.counts)}")

    def encode(self) -> bytes:
        n = len(self.counts)
        return _seal(_DATA[n] + struct.pack(f">HH{n}h", self.counter, self.status, *self.counts))

    @property
    def daq_error(self) -> int:
        """Bits 15-13 of the status word (0 = none, 1 = DAQ error, 2 = communication)."""
        return self.status >> 13

    @property
    def sensor_error(self) -> int:
        """Bits 12-10 (flags: 1 = not detected, 2 = failure, 4 = temperature)."""
        return (self.status >> 10) & 0b111

    @property
    def valid(self) -> bool:
        """False when the DAQ or the sensor flags an error (status bits 10-15)."""
        return self.status & 0xFC00 == 0

    @property
    def overloaded(self) -> tuple[str, ...]:
        """Names of the overloaded axes (status bits 9-4: Fx, Fy, Fz, Tx, Ty, Tz)."""
        names = ("x", "y", "z", "tx", "ty", "tz")
        return tuple(n for i, n in enumerate(names) if self.status & (1 << (9 - i)))


@dataclass(frozen=True)
class ConfigCommand:
    """Host -> DAQ configuration: ``speed`` code, ``filter`` code, ``zero`` (0 or 255)."""

    speed: int
    filter: int
    zero: int = 0

    def encode(self) -> bytes:
        return _seal(_CONFIG + bytes([self.speed, self.filter, self.zero]))


@dataclass(frozen=True)
class ConfigAck:
    """DAQ -> host acknowledge of a configuration; ``result`` 0 means accepted."""

    result: int

    def encode(self) -> bytes:
        return _seal(_ACK + bytes([self.result]))


@dataclass(frozen=True)
class SerialRequest:
    """Host -> DAQ serial-number request (6 bytes, no payload)."""

    def encode(self) -> bytes:
        return _seal(_SERIAL_REQUEST)


@dataclass(frozen=True)
class SerialReply:
    """DAQ -> host serial number (8 ASCII characters, right-padded with spaces)."""

    serial: str

    def encode(self) -> bytes:
        text = self.serial.encode("ascii")
        if len(text) > 8:
            raise ValueError(f"a serial number has at most 8 characters, not {self.serial!r}")
        return _seal(_SERIAL_REPLY + text.ljust(8))


Message = DataFrame | ConfigAck | ConfigCommand | SerialReply | SerialRequest


def _decode_data(frame: bytes) -> DataFrame:
    n = (len(frame) - 10) // 2
    counter, status, *counts = struct.unpack(f">HH{n}h", frame[4:-2])
    return DataFrame(counter, status, tuple(counts))


_DECODERS = {
    "daq": {
        **{h: (6 + 2 * (n + 2), _decode_data) for n, h in _DATA.items()},
        _ACK: (7, lambda f: ConfigAck(f[4])),
        _SERIAL_REPLY: (14, lambda f: SerialReply(f[4:12].decode("ascii", "replace").strip())),
    },
    "host": {
        _CONFIG: (9, lambda f: ConfigCommand(f[4], f[5], f[6])),
        _SERIAL_REQUEST: (6, lambda f: SerialRequest()),
    },
}
#: Directions a parser can read: what a DAQ sends, or what a host sends.
DAQ_TO_HOST = "daq"
HOST_TO_DAQ = "host"


class FrameParser:
    """Incremental parser of one direction of the OptoForce byte stream.

    Feed it chunks with :meth:`feed`; it returns every complete message found.
    Follows the reference's robust reader (section 4.5): skip to a start byte,
    accept only known headers, and on a checksum failure drop *one* byte so a
    true frame starting inside the bad one is not lost.

    Parameters
    ----------
    direction : {"daq", "host"}
        Parse what the DAQ sends (data, acknowledges, serial numbers; the
        default) or what a host sends (configuration, serial request).
    counter_step : int, optional
        Expected counter increment between frames; learned from the first two
        frames when omitted (and lowered if a smaller positive step is seen).
        The counter is forgotten, and the step learned anew, at every acknowledge
        of a configuration.

    A data frame whose counter does not follow the previous one by the step is held
    back until the next frame (one frame period): kept when its counter lies between
    its neighbours' (samples were lost before it), dropped and counted corrupted when
    it does not. The checksum is a plain sum, blind to swapped bytes (reference
    section 3), and one frame's wrong counter would otherwise shift every later
    sample by up to 65 536 samples. :meth:`flush` releases a held frame.

    Attributes
    ----------
    frames_valid : int
        Data frames returned (passed the checksum and the counter's check).
    frames_corrupted : int
        Messages with a known header whose checksum failed, and data frames whose
        counter contradicts both neighbours'.
    bytes_discarded : int
        Bytes skipped while searching for a header (garbage, broken frames).
    samples_lost : int
        Samples missing according to the counter (includes corrupted frames).
    """

    def __init__(self, direction: str = DAQ_TO_HOST, counter_step: int | None = None) -> None:
        if direction not in _DECODERS:
            raise ValueError(f"direction must be 'daq' or 'host', not {direction!r}")
        self._decoders = _DECODERS[direction]
        self._buf = bytearray()
        self.frames_valid = 0
        self.frames_corrupted = 0
        self.bytes_discarded = 0
        self.samples_lost = 0
        self._given_step = counter_step
        self._held: DataFrame | None = None
        self.restart_counter()

    def restart_counter(self) -> None:
        """Forget the last counter and the learned step (done at every acknowledge, after
        :meth:`flush`)."""
        self.counter_step = self._given_step
        self._last_counter: int | None = None

    def flush(self) -> list[DataFrame]:
        """Release the frame held back for its successor's counter (none: ``[]``)."""
        held, self._held = self._held, None
        return [] if held is None else [self._accept(held)]

    def _accept(self, frame: DataFrame) -> DataFrame:
        """Count ``frame`` valid and set its ``lost_before`` from the counter."""
        self.frames_valid += 1
        last, self._last_counter = self._last_counter, frame.counter
        if last is None:
            return frame
        diff = _ahead(last, frame.counter)
        if diff == 0:
            return frame  # a repeated counter: nothing is known to be lost
        if self.counter_step is None or diff < self.counter_step:
            self.counter_step = diff
            return frame
        lost = max(round(diff / self.counter_step) - 1, 0)
        self.samples_lost += lost
        return DataFrame(frame.counter, frame.status, frame.counts, lost) if lost else frame

    def _sequence(self, frame: DataFrame) -> list[DataFrame]:
        """The data frames that ``frame`` releases, in order (see the class docstring)."""
        out = []
        held, self._held = self._held, None
        last = self._last_counter
        if held is not None:
            assert last is not None  # a frame is held only after an accepted one
            if _ahead(last, held.counter) + _ahead(held.counter, frame.counter) == _ahead(
                    last, frame.counter):
                out.append(self._accept(held))
                last = held.counter
            else:  # the held counter lies outside its neighbours': wrong, though summed right
                self.frames_corrupted += 1
        step = self.counter_step
        if last is not None and step is not None and _ahead(last, frame.counter) != step:
            self._held = frame
        else:
            out.append(self._accept(frame))
        return out

    def feed(self, data: bytes) -> list[Message]:
        """Append ``data`` and return the complete messages now available, in order."""
        buf = self._buf
        buf += data
        out: list[Message] = []
        pos = 0
        while True:
            start = buf.find(b"\xaa", pos)
            start_ab = buf.find(b"\xab", pos)
            if start_ab != -1 and (start == -1 or start_ab < start):
                start = start_ab
            if start == -1:
                self.bytes_discarded += len(buf) - pos
                pos = len(buf)
                break
            self.bytes_discarded += start - pos
            pos = start
            if len(buf) - pos < 4:
                break
            entry = self._decoders.get(bytes(buf[pos:pos + 4]))
            if entry is None:
                self.bytes_discarded += 1
                pos += 1
                continue
            length, decode = entry
            if len(buf) - pos < length:
                break
            frame = bytes(buf[pos:pos + length])
            if checksum(frame[:-2]) != int.from_bytes(frame[-2:], "big"):
                self.frames_corrupted += 1
                self.bytes_discarded += 1
                pos += 1
                continue
            msg = decode(frame)
            if isinstance(msg, DataFrame):
                out += self._sequence(msg)
            else:
                if isinstance(msg, ConfigAck):  # a new configuration: the step may change
                    out += self.flush()
                    self.restart_counter()
                out.append(msg)
            pos += length
        del buf[:pos]
        return out


def _ahead(a: int, b: int) -> int:
    """How far counter ``b`` is ahead of ``a``, modulo the 16-bit wrap."""
    return (b - a) & 0xFFFF


def axis_names(n_counts: int) -> tuple[str, ...]:
    """Column suffixes for a frame of ``n_counts`` values: x,y,z / 4 channels / 6 axes."""
    if n_counts == 12:
        return tuple(f"{c}{a}" for c in range(1, 5) for a in _AXES[3])
    return _AXES[n_counts]
