"""A fake Dynamixel X-series servo on a pty, answering Protocol 2.0 (reference section 10)."""

from __future__ import annotations

import os
import pty
import struct
import threading
import time
import tty

from frictionfit.acquisition.dynamixel import PING, READ, STATUS, WRITE, Packet, PacketParser

MODEL_XM430_W350 = 1020


class FakeDynamixel:
    """Servo ``servo_id`` at ``self.url``; logs every goal position it is sent.

    The present position follows the goal at ``speed`` counts per second.
    ``spoil`` maps the number of a Present Position read (1 for the first) to
    ``"crc"`` (its reply's CRC is broken) or ``"late"`` (its reply comes ``late_s``
    seconds late); ``position_reads`` counts the reads. In position mode (3) a goal
    outside the Min/Max Position Limit is refused with error 6 (data limit); a READ of
    an address the fake does not hold gets error 7 (access). ``overload_at_goal``: the
    n-th goal written (1 for the first) latches an overload, as a stalled finger would;
    from then on every status carries the alert bit and goals are ignored.
    """

    def __init__(self, servo_id: int = 1, position: int = 2048, speed: float = 2000.0,
                 spoil: dict[int, str] | None = None, late_s: float = 0.15, mode: int = 3,
                 limits: tuple[int, int] = (0, 4095), overload_at_goal: int | None = None
                 ) -> None:
        self.servo_id, self.speed = servo_id, speed
        self.spoil, self.late_s = dict(spoil or {}), late_s
        self.overload_at_goal = overload_at_goal
        self.position_reads = 0
        self.table = {0: struct.pack("<H", MODEL_XM430_W350), 11: bytes([mode]),
                      48: struct.pack("<i", limits[1]), 52: struct.pack("<i", limits[0]),
                      64: b"\x00", 70: b"\x00",
                      116: struct.pack("<i", position), 132: struct.pack("<i", position)}
        self.goals: list[int] = []
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.url = os.ttyname(self._slave)
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fake dynamixel", daemon=True)
        self._last = time.monotonic()

    def _advance(self) -> None:
        now = time.monotonic()
        step, self._last = self.speed * (now - self._last), now
        pos = struct.unpack("<i", self.table[132])[0]
        goal = struct.unpack("<i", self.table[116])[0]
        pos = goal if abs(goal - pos) <= step else pos + int(step) * (1 if goal > pos else -1)
        self.table[132] = struct.pack("<i", pos)

    def _reply(self, pkt: Packet) -> tuple[int, bytes]:
        """The error number and the data of the status answering ``pkt``."""
        if pkt.instruction == PING:
            return 0, self.table[0] + b"\x2e"
        addr = struct.unpack_from("<H", pkt.params)[0]
        if pkt.instruction == READ:
            self._advance()
            if addr not in self.table:
                return 7, b""
            return 0, self.table[addr][: struct.unpack_from("<H", pkt.params, 2)[0]]
        if pkt.instruction == WRITE and addr == 116:
            goal = struct.unpack("<i", pkt.params[2:])[0]
            lo, hi = (struct.unpack("<i", self.table[a])[0] for a in (52, 48))
            if self.table[11] == b"\x03" and not lo <= goal <= hi:
                return 6, b""
            self.goals.append(goal)
            if len(self.goals) == self.overload_at_goal:
                self.table[70] = b"\x20"
            if self.table[70] != b"\x00":
                return 0, b""  # torque off: the goal is ignored
        if pkt.instruction == WRITE:
            self.table[addr] = pkt.params[2:]
        return 0, b""

    def _run(self) -> None:
        parser = PacketParser()
        while not self._halt.is_set():
            try:
                data = os.read(self._master, 4096)
            except OSError:  # nothing to read yet
                time.sleep(0.001)
                continue
            for pkt in parser.feed(data):
                if pkt.id == self.servo_id and pkt.instruction != STATUS:
                    number, data = self._reply(pkt)
                    alert = 0x80 if self.table[70] != b"\x00" else 0
                    reply = Packet(self.servo_id, STATUS, bytes([alert | number]) + data)
                    os.write(self._master, self._spoiled(pkt, reply.encode()))

    def _spoiled(self, pkt: Packet, reply: bytes) -> bytes:
        if pkt.instruction != READ or struct.unpack_from("<H", pkt.params)[0] != 132:
            return reply
        self.position_reads += 1
        how = self.spoil.get(self.position_reads)
        if how == "crc":
            return reply[:-1] + bytes([reply[-1] ^ 1])
        if how == "late":
            time.sleep(self.late_s)
        return reply

    def __enter__(self) -> FakeDynamixel:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._halt.set()
        self._thread.join(5)
        os.close(self._master)
        os.close(self._slave)
