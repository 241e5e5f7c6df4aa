"""The OptoForce codec against the reference's real and constructed byte vectors."""

import pytest

from frictionfit.acquisition.frames import (
    ConfigAck,
    ConfigCommand,
    DataFrame,
    FrameParser,
    SerialReply,
    SerialRequest,
    axis_names,
)

# reference section 12.2: the start of a real capture (acknowledge, then three frames)
REAL_STREAM = bytes.fromhex(
    "AA 00 50 01 00 00 FB"
    "AA 07 08 0A 2D 6A 00 00 FF F7 FF FB 00 07 05 51"
    "AA 07 08 0A 2D 6B 00 00 FF F9 FF FE 00 0C 05 5C"
    "AA 07 08 0A 2D 6C 00 00 FF F3 00 01 00 0A 03 59"
)


def test_real_capture_decodes():
    msgs = FrameParser().feed(REAL_STREAM)
    assert msgs[0] == ConfigAck(0)
    assert [(m.counter, *m.counts) for m in msgs[1:]] == [
        (11626, -9, -5, 7), (11627, -7, -2, 12), (11628, -13, 1, 10)]


@pytest.mark.parametrize("cut", range(len(REAL_STREAM) + 1))
def test_truncated_stream_yields_only_complete_frames(cut):
    complete = sum(1 for end in (7, 23, 39, 55) if end <= cut)
    assert len(FrameParser().feed(REAL_STREAM[:cut])) == complete


def test_byte_by_byte_equals_one_chunk():
    parser = FrameParser()
    one_by_one = [m for b in REAL_STREAM for m in parser.feed(bytes([b]))]
    assert one_by_one == FrameParser().feed(REAL_STREAM)


@pytest.mark.parametrize(("msg", "hexbytes"), [
    (DataFrame(0, 0, (401, -802, 16037)), "AA 07 08 0A 00 00 00 00 01 91 FC DE 3E A5 04 12"),
    (DataFrame(513, 0x0200, (120, -80, 3000, -15, 40, 7)),
     "AA 07 08 10 02 01 02 00 00 78 FF B0 0B B8 FF F1 00 28 00 07 05 D7"),
    (ConfigCommand(10, 4, 0), "AA 00 32 03 0A 04 00 00 ED"),
    (ConfigCommand(10, 4, 255), "AA 00 32 03 0A 04 FF 01 EC"),
    (ConfigCommand(1, 1, 255), "AA 00 32 03 01 01 FF 01 E0"),
    (ConfigCommand(0, 4, 0), "AA 00 32 03 00 04 00 00 E3"),
    (SerialRequest(), "AB 00 12 08 00 C5"),
    (SerialReply("ISE0A129"), "AA 00 12 08 49 53 45 30 41 31 32 39 02 B2"),
])
def test_reference_vectors(msg, hexbytes):
    raw = bytes.fromhex(hexbytes)
    assert msg.encode() == raw
    direction = "host" if isinstance(msg, (ConfigCommand, SerialRequest)) else "daq"
    assert FrameParser(direction).feed(raw) == [msg]


def test_status_flags():
    frame = FrameParser().feed(bytes.fromhex(
        "AA 07 08 10 02 01 02 00 00 78 FF B0 0B B8 FF F1 00 28 00 07 05 D7"))[0]
    assert frame.overloaded == ("x",) and frame.valid
    broken = DataFrame(1, (1 << 13) | (2 << 10), (0, 0, 0))
    assert (broken.daq_error, broken.sensor_error, broken.valid) == (1, 2, False)


def test_four_channel_frame_round_trip():
    frame = DataFrame(7, 0b1010, tuple(range(-6, 6)))
    assert len(frame.encode()) == 34
    assert FrameParser().feed(frame.encode()) == [frame]
    assert axis_names(12)[:4] == ("1x", "1y", "1z", "2x")


def test_bad_checksum_is_counted_and_next_frame_recovered():
    good = [DataFrame(c, 0, (c, -c, 2 * c)).encode() for c in range(4)]
    bad = bytearray(good[2])
    bad[9] ^= 0x40
    parser = FrameParser()
    msgs = parser.feed(b"\x00\xaa\x07" + good[0] + good[1] + bytes(bad) + good[3])
    assert [m.counter for m in msgs] == [0, 1]  # 3 waits for its successor's counter
    msgs += parser.flush()
    assert [m.counter for m in msgs] == [0, 1, 3]
    assert (parser.frames_valid, parser.frames_corrupted, parser.samples_lost) == (3, 1, 1)
    assert msgs[2].lost_before == 1


def test_counter_wraps_and_step_is_learned():
    parser = FrameParser()
    counters = [65530, 65533, 0, 6]  # step 3; 65533 -> 0 wraps; 0 -> 6 loses one
    msgs = parser.feed(b"".join(DataFrame(c, 0, (0, 0, 0)).encode() for c in counters))
    msgs += parser.flush()
    assert parser.counter_step == 3
    assert [m.lost_before for m in msgs] == [0, 0, 0, 1]


def _counters(counters, parser=None):
    parser = parser or FrameParser()
    msgs = parser.feed(b"".join(DataFrame(c, 0, (c & 0x7FFF, 0, 0)).encode() for c in counters))
    return [(m.counter, m.lost_before) for m in msgs + parser.flush()], parser


def test_a_counter_that_passes_the_checksum_but_contradicts_its_neighbours_is_dropped():
    frames = [DataFrame(c, 0, (1, 2, 3)).encode() for c in range(0x0100, 0x0108)]
    swapped = bytearray(frames[4])
    swapped[4], swapped[5] = swapped[5], swapped[4]  # 0x0104 -> 0x0401: the sum holds
    frames[4] = bytes(swapped)
    parser = FrameParser()
    msgs = parser.feed(b"".join(frames)) + parser.flush()
    # kept, it said 0x0401 - 0x0103 - 1 = 765 samples were lost, then 64,770 more
    assert [(m.counter, m.lost_before) for m in msgs] == [
        (0x0100, 0), (0x0101, 0), (0x0102, 0), (0x0103, 0), (0x0105, 1), (0x0106, 0),
        (0x0107, 0)]
    assert (parser.frames_valid, parser.frames_corrupted, parser.samples_lost) == (7, 1, 1)


@pytest.mark.parametrize(("counters", "expected"), [
    # true losses are kept, however long, across the wrap too
    ([10, 11, 60, 61], [(10, 0), (11, 0), (60, 48), (61, 0)]),
    ([65534, 65535, 4, 5], [(65534, 0), (65535, 0), (4, 4), (5, 0)]),
    # two losses in a row, and a loss just before the stream ends (flushed)
    ([1, 2, 5, 9, 10, 12], [(1, 0), (2, 0), (5, 2), (9, 3), (10, 0), (12, 1)]),
    # a repeated counter, and a step learned too large from a lost second frame
    ([7, 8, 8, 9], [(7, 0), (8, 0), (8, 0), (9, 0)]),
    ([0, 20, 30, 40], [(0, 0), (20, 0), (30, 0), (40, 0)]),
    # a wrong counter in frame 3's place: dropped, its slot lost before the next frame
    ([1, 2, 40000, 4, 5], [(1, 0), (2, 0), (4, 1), (5, 0)]),
])
def test_counter_check_keeps_true_losses(counters, expected):
    assert _counters(counters)[0] == expected


def test_a_configuration_acknowledge_releases_a_held_frame():
    parser = FrameParser()
    stream = b"".join(DataFrame(c, 0, (0, 0, 0)).encode() for c in (1, 2, 5))
    msgs = parser.feed(stream + ConfigAck(0).encode() + DataFrame(100, 0, (0, 0, 0)).encode())
    assert [(type(m).__name__, getattr(m, "lost_before", None)) for m in msgs] == [
        ("DataFrame", 0), ("DataFrame", 0), ("DataFrame", 2), ("ConfigAck", None),
        ("DataFrame", 0)]


def test_host_stream_ignores_daq_frames():
    stream = DataFrame(1, 0, (1, 2, 3)).encode() + ConfigCommand(1, 0, 0).encode()
    assert FrameParser("host").feed(stream) == [ConfigCommand(1, 0, 0)]


def test_errors_in_words():
    with pytest.raises(ValueError, match="3, 6 or 12 counts"):
        DataFrame(0, 0, (1, 2))
    with pytest.raises(ValueError, match="at most 8 characters"):
        SerialReply("TOO-LONG-1").encode()
    with pytest.raises(ValueError, match="direction must be"):
        FrameParser("both")
