"""Dynamixel Protocol 2.0 codec against the reference's packets; actuators; the protocol."""

import struct
import time

import numpy as np
import pytest

from frictionfit.acquisition.actuator import DynamixelActuator, SimulatedGripper
from frictionfit.acquisition.dynamixel import (
    PING,
    STATUS,
    WRITE,
    Packet,
    PacketParser,
    crc16,
)
from frictionfit.acquisition.protocol import RubbingProtocol
from frictionfit.errors import AcquisitionError

# reference section 4 (e-Manual examples) and section 9 (recipes)
REFERENCE_PACKETS = [
    "FF FF FD 00 01 03 00 01 19 4E",
    "FF FF FD 00 FE 03 00 01 31 42",
    "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15",
    "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0",
    "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89",
    "FF FF FD 00 01 04 00 55 00 A1 0C",
    "FF FF FD 00 01 03 00 08 2F 4E",
    "FF FF FD 00 01 07 00 02 00 00 02 00 21 51",
    "FF FF FD 00 01 06 00 55 00 FC 03 C3 53",
    "FF FF FD 00 01 06 00 03 40 00 00 DE E6",
    "FF FF FD 00 01 06 00 03 0B 00 03 48 E3",
    "FF FF FD 00 01 07 00 03 66 00 64 00 4E 7D",
    "FF FF FD 00 01 09 00 03 74 00 00 08 00 00 42 89",
    "FF FF FD 00 01 08 00 55 00 00 08 00 00 1C 38",
    "FF FF FD 00 01 08 00 55 00 0C FE FF FF A9 44",
    "FF FF FD 00 01 05 00 55 00 01 56 A1",
    "FF FF FD 00 01 0A 00 03 74 00 FF FF FD FD FF 23 E5",  # byte stuffing
    "FF FF FD 00 01 04 00 55 04 BA 8C",
    "FF FF FD 00 01 04 00 55 80 A2 8F",
]


def test_crc_check_value():
    assert crc16(b"123456789") == 0xFEE8


@pytest.mark.parametrize("hexbytes", REFERENCE_PACKETS)
def test_reference_packets_decode_and_reencode(hexbytes):
    raw = bytes.fromhex(hexbytes)
    (pkt,) = PacketParser().feed(b"\x00\xff" + raw)
    assert pkt.encode() == raw


def test_packets_by_meaning():
    assert Packet(1, WRITE, struct.pack("<Hi", 116, 2048)).encode() == bytes.fromhex(
        "FF FF FD 00 01 09 00 03 74 00 00 08 00 00 42 89")
    goal = Packet(1, WRITE, struct.pack("<Hi", 116, -131073))
    assert goal.encode() == bytes.fromhex("FF FF FD 00 01 0A 00 03 74 00 FF FF FD FD FF 23 E5")
    (back,) = PacketParser().feed(goal.encode())
    assert struct.unpack("<Hi", back.params) == (116, -131073)
    (status,) = PacketParser().feed(bytes.fromhex("FF FF FD 00 01 08 00 55 00 0C FE FF FF A9 44"))
    assert (status.error, struct.unpack("<i", status.data)[0]) == (0, -500)


def test_bad_crc_is_counted_and_skipped():
    bad = bytearray(bytes.fromhex("FF FF FD 00 01 04 00 55 00 A1 0C"))
    bad[-1] ^= 1
    parser = PacketParser()
    good = Packet(1, PING).encode()
    assert parser.feed(bytes(bad) + good) == [Packet(1, PING)] and parser.crc_errors == 1


@pytest.fixture
def servo():
    actuator = DynamixelActuator("loop://", 1, limits=(0, 4095))
    yield actuator
    actuator.close()


def _answer(servo, raw):
    """Put ``raw`` on the loop right after the servo's next request, as a servo would."""
    send = servo.port.write

    def request(data):
        servo.port.write = send
        written = send(data)
        send(raw)
        return written

    servo.port.write = request


def _reply(servo, error=0, data=b""):
    _answer(servo, Packet(1, STATUS, bytes([error]) + data).encode())


def test_dynamixel_on_loop(servo):
    _reply(servo, data=struct.pack("<HB", 1020, 46))
    assert servo.ping() == 1020
    _reply(servo)
    servo.move_to(2048)
    _answer(servo, bytes.fromhex("FF FF FD 00 01 08 00 55 00 0C FE FF FF A9 44"))
    assert servo.position() == -500.0


@pytest.mark.parametrize(("hexbytes", "words"), [
    ("FF FF FD 00 01 04 00 55 04 BA 8C", r"error 4 \(data range error\)"),
    ("FF FF FD 00 01 04 00 55 80 A2 8F", "cannot WRITE 100 at 116: a hardware error is "
     "latched"),
])
def test_dynamixel_errors_in_words(servo, hexbytes, words):
    _answer(servo, bytes.fromhex(hexbytes))
    with pytest.raises(AcquisitionError, match=words):
        servo.move_to(100)


def test_dynamixel_limits_and_silence(servo):
    with pytest.raises(AcquisitionError, match="goal position 5000 is outside .* 0..4095"):
        servo.move_to(5000)
    with pytest.raises(AcquisitionError, match="no status from servo 1 for READ position"):
        servo.position()


def test_a_late_reply_is_dropped_not_taken_for_the_next():
    from fake_dynamixel import FakeDynamixel

    with FakeDynamixel(position=2048, speed=1e9, spoil={1: "late"}, late_s=0.15) as fake:
        servo = DynamixelActuator(fake.url, position_timeout_s=0.05)
        try:
            with pytest.raises(AcquisitionError, match="no status .* READ position within 0.05"):
                servo.position()
            time.sleep(0.2)  # the late reply (2048) is waiting in the port
            servo.move_to(1000)  # kept, it would pass for this status: all later off by one
            assert servo.position() == 1000.0 and servo.position() == 1000.0
        finally:
            servo.close()
    assert fake.goals == [1000] and fake.position_reads == 3


def test_a_reply_with_a_bad_crc_is_a_timeout():
    from fake_dynamixel import FakeDynamixel

    with FakeDynamixel(position=1500, spoil={1: "crc"}) as fake:
        servo = DynamixelActuator(fake.url, position_timeout_s=0.05)
        try:
            with pytest.raises(AcquisitionError, match="no status from servo 1 for READ"):
                servo.position()
            assert servo.parser.crc_errors == 1 and servo.position() == 1500.0
        finally:
            servo.close()


@pytest.mark.parametrize(("mode", "limits", "expected"), [
    (3, (100, 3000), (100, 3000)),  # position mode: the servo's own Min/Max Position Limit
    (4, (0, 4095), (-1_048_575, 1_048_575)),  # extended position: +-256 turns
    (5, (0, 4095), (-1_048_575, 1_048_575)),  # current-based position, a gripper's mode
])
def test_prepare_learns_the_limits_from_the_servo(mode, limits, expected):
    from fake_dynamixel import FakeDynamixel

    with FakeDynamixel(position=1000, speed=1e9, mode=mode, limits=limits) as fake:
        servo = DynamixelActuator(fake.url)
        try:
            assert servo.prepare() == 1020 and servo.limits == expected
            assert fake.table[64] == b"\x01"  # torque on
            servo.move_to(-500 if mode != 3 else 2500)
            assert servo.position() == (-500.0 if mode != 3 else 2500.0)
            with pytest.raises(AcquisitionError, match=f"outside servo 1's limits "
                               f"{expected[0]}..{expected[1]}"):
                servo.move_to(expected[1] + 1)
        finally:
            servo.close()


def test_a_servo_that_ignores_goal_positions_is_refused_in_words():
    from fake_dynamixel import FakeDynamixel

    with FakeDynamixel(mode=1) as fake:
        servo = DynamixelActuator(fake.url)
        try:
            with pytest.raises(AcquisitionError, match=r"servo 1 is in velocity control "
                               r"\(Operating Mode 1\), where it ignores goal positions"):
                servo.prepare()
        finally:
            servo.close()
        assert fake.table[64] == b"\x00"  # the torque was left off


def test_a_latched_overload_is_named():
    from fake_dynamixel import FakeDynamixel

    with FakeDynamixel(position=1000, overload_at_goal=1) as fake:
        servo = DynamixelActuator(fake.url)
        try:
            servo.prepare()
            with pytest.raises(AcquisitionError, match=(
                    r"servo 1 cannot WRITE 1200 at 116: hardware error overload \(address 70 "
                    r"= 0x20\); the servo may have switched its torque off")):
                servo.move_to(1200)
            with pytest.raises(AcquisitionError, match="cannot READ position: hardware error "
                               "overload"):
                servo.position()
        finally:
            servo.close()
    with FakeDynamixel(limits=(0, 3000)) as fake:  # the servo refuses a goal itself
        servo = DynamixelActuator(fake.url, limits=(0, 4095))
        try:
            with pytest.raises(AcquisitionError, match=r"refused WRITE 3500 at 116: error 6 "
                               r"\(data limit error\)"):
                servo.move_to(3500)
        finally:
            servo.close()


def test_simulated_gripper_moves_like_the_model_drive():
    times = iter([0.0, 1.0, 3.0])
    g = SimulatedGripper(0.0, move_s=0.1, latency_s=0.02, clock=lambda: next(times))
    g.move_to(5.0)   # at t = 1.0
    g.move_to(-1.0)  # at t = 3.0
    x = g.trajectory(np.array([0.5, 1.02, 1.07, 1.2, 3.02, 3.5]))
    np.testing.assert_allclose(x, [0.0, 0.0, 2.5, 5.0, 5.0, -1.0])


def test_protocol_schedule_and_errors():
    p = RubbingProtocol(10, 20, motions=5, dwell_s=1.0)
    assert [t for t, _ in p.schedule()][-2:] == [8.05, 9.05]
    assert p.duration_s == pytest.approx(10.05)
    with pytest.raises(ValueError, match="need motions >= 1"):
        RubbingProtocol(0, 1, motions=0)
