"""Dynamixel Protocol 2.0 packets as bytes and back: a pure codec, no I/O.

Layout, byte stuffing and CRC-16 (polynomial 0x8005, CRC-16/BUYPASS) follow the
team's ``reference/dynamixel-protocol2.md`` (sections 2-4). Multi-byte fields are
little-endian.

Examples
--------
>>> Packet(1, PING).encode().hex(" ").upper()
'FF FF FD 00 01 03 00 01 19 4E'
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

__all__ = ["PING", "READ", "STATUS", "WRITE", "Packet", "PacketParser", "crc16"]

HEADER = b"\xff\xff\xfd"
PING, READ, WRITE, STATUS = 0x01, 0x02, 0x03, 0x55


def _table() -> tuple[int, ...]:
    out = []
    for v in range(256):
        crc = v << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
        out.append(crc)
    return tuple(out)


_TABLE = _table()


def crc16(data: bytes) -> int:
    """CRC-16/BUYPASS of ``data`` (check value ``crc16(b"123456789") == 0xFEE8``)."""
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ _TABLE[(crc >> 8) ^ b]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` in the instruction and parameters."""
    return body.replace(HEADER, HEADER + b"\xfd")


def unstuff(body: bytes) -> bytes:
    """Undo :func:`stuff`: ``FF FF FD FD`` -> ``FF FF FD``."""
    return body.replace(HEADER + b"\xfd", HEADER)


@dataclass(frozen=True)
class Packet:
    """An instruction (host -> servo) or a status (``instruction == STATUS``) packet.

    For a status packet ``params[0]`` is the error byte (see :attr:`error`) and the
    rest is the data.
    """

    id: int
    instruction: int
    params: bytes = b""

    def encode(self) -> bytes:
        body = stuff(bytes([self.instruction]) + self.params)
        head = HEADER + b"\x00" + bytes([self.id]) + struct.pack("<H", len(body) + 2) + body
        return head + struct.pack("<H", crc16(head))

    @property
    def error(self) -> int:
        """Error byte of a status packet: bit 7 alert, bits 0-6 the error number."""
        return self.params[0] if self.instruction == STATUS and self.params else 0

    @property
    def data(self) -> bytes:
        """Parameters after the error byte of a status packet."""
        return self.params[1:] if self.instruction == STATUS else self.params


class PacketParser:
    """Incremental parser: feed bytes, get whole packets; bad CRCs are counted and skipped.

    A header is ``FF FF FD`` not followed by ``FD``; the CRC is checked over the
    bytes as received, then the body is unstuffed.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.crc_errors = 0

    def clear(self) -> None:
        """Drop the bytes buffered so far (a partial packet included)."""
        self._buf.clear()

    def feed(self, data: bytes) -> list[Packet]:
        buf = self._buf
        buf += data
        out: list[Packet] = []
        pos = 0
        while True:
            start = buf.find(HEADER, pos)
            if start == -1:
                pos = max(len(buf) - 2, pos)
                break
            pos = start
            if len(buf) - pos < 7:
                break
            if buf[pos + 3] != 0x00:  # FF FF FD FD is stuffing, not a header
                pos += 1
                continue
            length = struct.unpack_from("<H", buf, pos + 5)[0]
            if len(buf) - pos < 7 + length:
                break
            raw = bytes(buf[pos:pos + 7 + length])
            if length < 3 or crc16(raw[:-2]) != struct.unpack("<H", raw[-2:])[0]:
                self.crc_errors += 1
                pos += 1
                continue
            body = unstuff(raw[7:-2])
            out.append(Packet(raw[4], body[0], body[1:]))
            pos += 7 + length
        del buf[:pos]
        return out
