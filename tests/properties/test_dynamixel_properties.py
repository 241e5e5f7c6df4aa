"""Hypothesis properties of the Dynamixel codec: stuffing and CRC round trips, no crash."""

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from frictionfit.acquisition.dynamixel import Packet, PacketParser, stuff, unstuff  # noqa: E402

# parameters rich in FF and FD, so that stuffing is exercised
params = st.lists(st.sampled_from([0xFF, 0xFD, 0x00, 0x55]) | st.integers(0, 255),
                  max_size=24).map(bytes)
packets = st.builds(Packet, st.integers(0, 252), st.integers(0, 255), params)


@settings(max_examples=300, deadline=None)
@given(params)
def test_unstuff_inverts_stuff(body):
    stuffed = stuff(body)
    assert unstuff(stuffed) == body
    i = stuffed.find(b"\xff\xff\xfd")
    while i != -1:  # a receiver never mistakes the body for a header
        assert stuffed[i + 3:i + 4] == b"\xfd"
        i = stuffed.find(b"\xff\xff\xfd", i + 4)


@settings(max_examples=300, deadline=None)
@given(st.lists(packets, max_size=6), st.integers(1, 40))
def test_packets_round_trip_in_any_chunking(pkts, chunk):
    stream = b"".join(p.encode() for p in pkts)
    parser = PacketParser()
    got = [q for i in range(0, len(stream), chunk) for q in parser.feed(stream[i:i + chunk])]
    assert got == pkts and parser.crc_errors == 0


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_arbitrary_bytes_never_crash(data):
    for pkt in PacketParser().feed(data):
        assert 0 <= pkt.id <= 255
