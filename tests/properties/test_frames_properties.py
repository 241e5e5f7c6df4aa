"""Hypothesis properties of the OptoForce codec: no crash, no lost frame, round trips."""

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from frictionfit.acquisition.frames import DataFrame, FrameParser  # noqa: E402

int16 = st.integers(-32768, 32767)
frames = st.builds(
    DataFrame,
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFF),
    st.one_of(st.tuples(int16, int16, int16), st.lists(int16, min_size=6, max_size=6).map(tuple),
              st.lists(int16, min_size=12, max_size=12).map(tuple)),
)
# noise that cannot contain a start byte, so it can never hide a frame's header
noise = st.binary(max_size=40).map(lambda b: bytes(x for x in b if x not in (0xAA, 0xAB)))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400), st.lists(st.integers(1, 64), max_size=20))
def test_arbitrary_bytes_never_crash(data, cuts):
    parser = FrameParser()
    pos = 0
    for n in cuts:
        parser.feed(data[pos:pos + n])
        pos += n
    msgs = parser.feed(data[pos:]) + parser.flush()
    assert parser.frames_valid <= len(data) // 16
    assert all(isinstance(m.counter, int) for m in msgs if isinstance(m, DataFrame))


@settings(max_examples=200, deadline=None)
@given(frames)
def test_encode_decode_round_trip(frame):
    assert FrameParser().feed(frame.encode()) == [frame]


def _numbered(fs: list[DataFrame], first: int, gaps: list[int]) -> list[DataFrame]:
    """``fs`` as a DAQ sends them: counters from ``first`` up (wrapping at 65536), with
    ``gaps[i]`` samples lost before frame ``i > 0``."""
    out, counter = [], first
    for i, f in enumerate(fs):
        counter += (1 + gaps[i]) if i else 0
        out.append(DataFrame(counter & 0xFFFF, f.status, f.counts))
    return out


gaps = st.lists(st.one_of(st.just(0), st.just(0), st.integers(1, 3000)), min_size=12,
                max_size=12)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(noise, frames), max_size=12), noise, st.integers(1, 50),
       st.integers(0, 0xFFFF), gaps)
def test_frames_in_noise_are_all_recovered(pieces, tail, chunk, first, lost):
    lost = [0, 0, *lost[2:]]  # the first two frames teach the step
    sent = _numbered([f for _, f in pieces], first, lost)
    stream = b"".join(n + f.encode() for (n, _), f in zip(pieces, sent, strict=True)) + tail
    parser = FrameParser()
    got = [m for i in range(0, len(stream), chunk) for m in parser.feed(stream[i:i + chunk])]
    got += parser.flush()
    assert [(m.counter, m.status, m.counts) for m in got] == [
        (f.counter, f.status, f.counts) for f in sent]
    assert [m.lost_before for m in got] == lost[:len(sent)]
    assert parser.frames_corrupted == 0


@settings(max_examples=150, deadline=None)
@given(st.lists(frames, min_size=1, max_size=8), st.binary(min_size=1, max_size=30),
       st.integers(0, 0xFFFF))
def test_frames_after_a_partial_frame_are_recovered(fs, prefix, first):
    # a frame cut short (the port opened mid-frame) followed by whole frames
    fs = _numbered(fs, first, [0] * len(fs))
    stream = fs[0].encode()[: len(prefix) % 10 + 1] + b"".join(f.encode() for f in fs)
    parser = FrameParser()
    got = parser.feed(stream) + parser.flush()
    assert [m.counts for m in got][-len(fs):] == [f.counts for f in fs]
