"""Rubbing feature sets (handcrafted, fftbins, raw, physical measured) vs hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from frictionfit.errors import RecordingError
from frictionfit.features._base import FeatureWarning
from frictionfit.features.fftbins import FFTBinFeatures, amplitude_bins
from frictionfit.features.handcrafted import HandcraftedFeatures, phase_features
from frictionfit.features.physical import MEASURED, N_BASIC, PhysicalFeatures, measured_phase
from frictionfit.features.raw import RawSignalFeatures
from frictionfit.recording import Event, Recording
from frictionfit.segmentation import segment

RATE = 1000.0
CHANNELS = ("thumb_x", "thumb_y", "index_x", "index_y")


def motion_signal() -> np.ndarray:
    """One 2-s motion (out command at sample 50, back at 1050), piecewise linear, N.

    Out: 1 until 50, up to 3 at 150 (the peak), down to 2 at 550, flat to 1050.
    Back: down to 0 at 1150 (the peak), up to 0.5 at 1550, flat to the end.
    """
    knots_i = [0, 50, 150, 550, 1050, 1150, 1550, 1999]
    knots_x = [1.0, 1.0, 3.0, 2.0, 2.0, 0.0, 0.5, 0.5]
    return np.interp(np.arange(2000), knots_i, knots_x)


def hand_built(name: str = "hand", scale=(1.0, -2.0, 0.5, 0.25), **metadata) -> Recording:
    """Two identical motions (the first is dropped as preparatory), channels scaled copies."""
    x = np.concatenate([motion_signal(), motion_signal(), np.full(50, 0.5)])
    samples = x[:, None] * np.asarray(scale)[None, :]
    events = [Event(0.05 + 2 * k + dt, "move", tgt)
              for k in range(2) for dt, tgt in ((0.0, "p2"), (1.0, "p1"))]
    return Recording.from_arrays(samples, RATE, CHANNELS, events=events, name=name,
                                 metadata={"label": "hand", **metadata})


def test_hand_built_recording_has_one_motion_at_the_commands():
    (m,) = segment(hand_built())
    assert (m.index, m.t_out, m.t_back) == (1, pytest.approx(0.05), pytest.approx(1.05))
    np.testing.assert_allclose(m.samples[:, 0], motion_signal())


def test_phase_features_by_hand():
    x = motion_signal()
    assert phase_features(x, RATE, 50, 1050, 300) == pytest.approx((3.0, 0.1, 2.5, 2.0))
    assert phase_features(x, RATE, 1050, 2000, 300) == pytest.approx((0.0, 0.1, 1.25, 0.5))


def test_phase_features_all_missing_is_nan():
    x = np.full(100, np.nan)
    assert np.isnan(phase_features(x, RATE, 0, 100, 30)).all()


def test_handcrafted_features_by_hand():
    f = HandcraftedFeatures(filter_n=1, cache=False)
    x = f.fit_transform([hand_built()])
    names = list(f.get_feature_names_out())
    assert len(names) == 40 and x.shape == (1, 40)
    row = dict(zip(names, x[0], strict=True))
    expected = {"out_peak [N]": 3.0, "out_t_peak [s]": 0.1, "out_max_gradient [N/s]": 2.5,
                "out_static [N]": 2.0, "back_peak [N]": 0.0, "back_t_peak [s]": 0.1,
                "back_max_gradient [N/s]": 1.25, "back_static [N]": 0.5,
                "start [N]": 1.0, "end [N]": 0.5}
    for key, value in expected.items():
        assert row[f"thumb_x:{key}"] == pytest.approx(value), key
    # thumb_y is the signal times -2: values scale, times do not
    assert row["thumb_y:out_peak [N]"] == pytest.approx(-6.0)
    assert row["thumb_y:out_t_peak [s]"] == pytest.approx(0.1)


def test_handcrafted_without_time_drops_the_two_peak_times_per_channel():
    f = HandcraftedFeatures(with_time=False, cache=False)
    names = f.get_feature_names_out()
    assert len(names) == 32 and not any("_t_peak" in n for n in names)


def test_amplitude_bins_of_a_sine_by_hand():
    k = np.arange(20)
    x = 1.0 + 2.0 * np.sin(2 * np.pi * 5 * k / 20)
    # rfft gives 11 frequencies; array_split -> groups [0, 1], [2], [3], ..., [10]
    expected = np.zeros(10)
    expected[0] = 0.5  # mean of DC (1) and bin 1 (0)
    expected[4] = 2.0  # bin 5: the sine's amplitude
    np.testing.assert_allclose(amplitude_bins(x, 10), expected, atol=1e-12)


def test_fftbin_features_80_per_motion_and_offset_in_dc_only():
    f = FFTBinFeatures(cache=False)
    x = f.fit_transform([hand_built()])
    assert x.shape == (1, 80)
    names = list(f.get_feature_names_out())
    # thumb_x's back window (samples 1050..1199) is a V: 2 -> 0 -> 1.5*... its DC is its mean
    back = motion_signal()[1050:1200]
    assert x[0, names.index("thumb_x:back_fft_bin0 [N]")] == pytest.approx(
        amplitude_bins(back, 10)[0])
    assert x[0, names.index("index_y:out_fft_bin0 [N]")] > 0.0


def test_raw_features_are_baseline_free_waveforms():
    f = RawSignalFeatures(n_samples=1900, cache=False)
    x = f.fit_transform([hand_built()])
    assert x.shape == (1, 7600)
    np.testing.assert_allclose(x[0, :1900], motion_signal()[:1900] - 1.0)  # thumb_x
    np.testing.assert_allclose(x[0, 1900:3800], -2.0 * (motion_signal()[:1900] - 1.0))
    assert f.get_feature_names_out()[1900] == "thumb_y:t0.000 [N]"


def test_measured_phase_by_hand():
    x = motion_signal()
    got = dict(zip([n for n, _ in MEASURED], measured_phase(x, RATE, 50, 1050, 300),
                   strict=True))
    assert got["rise"] == pytest.approx(2.0)
    assert got["static"] == pytest.approx(1.0)
    assert got["relaxed_frac"] == pytest.approx(0.5)
    # 63% of the way from 3 down to 2 is 2.37, reached 252 samples after the peak
    assert got["t_relax"] == pytest.approx(0.252, abs=1.5e-3)
    assert got["onset_rate"] == pytest.approx(20.0)
    assert got["t_peak"] == pytest.approx(0.1)
    # 50/100/200/400 ms after the peak the signal is 2.875, 2.75, 2.5, 2.0: minus 1, over 2
    curve = [got[f"relax_{ms}ms"] for ms in (50, 100, 200, 400)]
    assert curve == pytest.approx([0.9375, 0.875, 0.75, 0.5])
    assert 0.0 <= got["slip_ripple"] < 0.01  # piecewise linear: no stick-slip ripple


def test_physical_measured_features_are_offset_free():
    f = PhysicalFeatures(fitted=False, relaxation=True, cache=False)
    base = f.fit_transform([hand_built()])
    rec = hand_built()
    shifted = Recording.from_arrays(rec.samples + [5.0, -3.0, 0.2, 1.0], RATE, CHANNELS,
                                    events=rec.events, name="shifted")
    # the filtered peak is flat to rounding: adding an offset may move the argmax by one
    # sample (1 ms), which moves times by 1e-3 s and forces by far less
    np.testing.assert_allclose(f.transform([shifted]), base, rtol=1e-3, atol=1.5e-3)
    assert f.get_feature_names_out()[0] == "thumb_x:out_rise [N]"
    assert base.shape == (1, 4 * 2 * len(MEASURED))
    basic = PhysicalFeatures(shape=False, relaxation=True, cache=False)
    assert basic.fit_transform([hand_built()]).shape == (1, 4 * 2 * N_BASIC)


def test_a_recording_without_motions_is_filled_and_named():
    good = [hand_built("a"), hand_built("b", scale=(2.0, -1.0, 1.0, 0.5))]
    bare = Recording.from_arrays(np.zeros((100, 4)), RATE, CHANNELS, name="no-events")
    f = HandcraftedFeatures(cache=False).fit(good)
    with pytest.warns(FeatureWarning, match="no-events"):
        x = f.transform([bare])
    np.testing.assert_allclose(x[0], f.fill_values_)


def test_a_missing_channel_is_named():
    rec = Recording.from_arrays(np.zeros((10, 1)), RATE, ["fx"], name="one-channel")
    with pytest.raises(RecordingError, match="thumb_x"):
        from frictionfit.features._rubbing import motions

        motions(rec, CHANNELS)


def test_the_quantities_read_off_the_force_mean_the_same_at_half_the_rate():
    """The moving averages span seconds, not samples: the same recording at 500 Hz gives
    the same stick-slip ripple and onset rate as at 1 kHz (with 9- and 25-sample windows
    the ripple's smooth part spanned twice the time at 500 Hz and the ripple doubled)."""
    from frictionfit.simulation.measurements import simulate_measurements

    recs = simulate_measurements([(1, "paper-2", 1), (1, "carpet-1", 1)], seed=4)
    halved = [Recording.from_arrays(r.samples[::2], 500.0, r.channel_names, events=r.events,
                                    name=f"{r.name}_500", metadata=r.metadata) for r in recs]
    f = PhysicalFeatures(cache=False)
    full, half = f.fit_transform(recs), f.transform(halved)
    names = list(f.get_feature_names_out())
    for quantity, tol in (("slip_ripple", 0.1), ("onset_rate", 0.1), ("rise", 0.02)):
        cols = [j for j, n in enumerate(names) if f"_{quantity} [" in n and "_x:" in n]
        assert np.median(np.abs(half[:, cols] / full[:, cols] - 1.0)) < tol, quantity
