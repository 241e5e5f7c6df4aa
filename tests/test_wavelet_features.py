"""The 270 published gesture features: each step against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest
import pywt
from scipy import ndimage, stats
from sklearn.base import clone

from frictionfit.datasets.gesture_skin import recording_from_frames
from frictionfit.features import make_features
from frictionfit.features.wavelet import (
    DESCRIPTORS,
    N_FEATURES,
    GestureFeatures,
    band_stats,
    frame_descriptors,
    gesture_feature_names,
    gesture_features,
    sequence_stats,
    upsample,
)

SQ2 = np.sqrt(2.0)


def test_upsample_equals_scipy_bicubic_zoom(rng):
    frames = rng.random((3, 20, 20)) * 50
    up = upsample(frames)
    assert up.shape == (3, 40, 40)
    for f, u in zip(frames, up, strict=True):
        np.testing.assert_allclose(u, ndimage.zoom(f, 2, order=3), atol=1e-10)


def test_upsample_keeps_a_constant_frame():
    np.testing.assert_allclose(upsample(np.full((1, 20, 20), 7.0)), 7.0, atol=1e-12)


def test_frame_descriptors_by_hand():
    frames = np.zeros((4, 3, 3))
    frames[0, 1, 1] = 9.0  # centre: mean 1, std sqrt(81/9 - 1) = sqrt(8)
    frames[1, 0, 0] = 4.0  # corner: mean 4/9, std sqrt(16/9 - 16/81) = 8 sqrt(2) / 9
    # frame 2 stays empty; frame 3: negative overshoot does not pull the centre of pressure
    frames[3, 0, 0] = -1.0
    frames[3, 2, 2] = 3.0
    d = dict(zip(DESCRIPTORS, frame_descriptors(frames), strict=True))
    np.testing.assert_allclose(d["mean"], [1.0, 4 / 9, 0.0, 2 / 9])
    np.testing.assert_allclose(d["max"], [9.0, 4.0, 0.0, 3.0])
    np.testing.assert_allclose(d["std"][:3], [np.sqrt(8.0), 8 * SQ2 / 9, 0.0])
    np.testing.assert_allclose(d["cop_dist"], [0.0, SQ2, 0.0, SQ2])
    np.testing.assert_allclose(d["peak_dist"], [0.0, SQ2, 0.0, SQ2])
    # one pixel above mean + std in frames 0, 1, 3; none in the empty frame
    np.testing.assert_array_equal(d["n_above"], [1, 1, 0, 1])


def test_distances_are_from_the_frame_centre_between_pixels():
    frames = np.zeros((1, 4, 4))
    frames[0, 0, 0] = 1.0  # centre of a 4 x 4 frame is (1.5, 1.5)
    frames_two = np.zeros((1, 4, 4))
    frames_two[0, 0, 0] = frames_two[0, 0, 3] = 1.0  # centre of pressure (0, 1.5)
    np.testing.assert_allclose(frame_descriptors(frames)[3:5, 0], [1.5 * SQ2, 1.5 * SQ2])
    np.testing.assert_allclose(frame_descriptors(frames_two)[3, 0], 1.5)


def test_sequence_stats_by_hand():
    # deviations -3 -2 -1 0 6: m2 = 10, m3 = 36, m4 = 278.8
    s = sequence_stats(np.array([[1.0, 2.0, 3.0, 4.0, 10.0]]))[0]
    np.testing.assert_allclose(
        s, [4.0, np.sqrt(10.0), 10.0, 9.0, 278.8 / 100 - 3, 36 / 10**1.5], rtol=1e-12
    )


def test_sequence_stats_match_scipy_and_are_zero_shape_for_a_constant(rng):
    x = rng.normal(size=(3, 40))
    s = sequence_stats(x)
    np.testing.assert_allclose(s[:, 4], stats.kurtosis(x, axis=1), rtol=1e-10)
    np.testing.assert_allclose(s[:, 5], stats.skew(x, axis=1), rtol=1e-10)
    np.testing.assert_array_equal(sequence_stats(np.full((1, 9), 3.0))[0], [3, 0, 0, 0, 0, 0])


def test_band_stats_of_a_constant_sequence_by_hand():
    # db8 periodization: details of a constant vanish; the approximation gains sqrt(2) per
    # level, so a10 = 2**5 * c = 32 c.
    out = band_stats(np.full((1, 150), 2.0))[0]
    assert out.shape == (39,)
    np.testing.assert_allclose(out[:38], 0.0, atol=1e-9)
    np.testing.assert_allclose(out[38], 64.0, rtol=1e-10)


def test_band_layout_matches_pywt_bands(rng):
    x = rng.normal(size=(1, 150))
    coeffs = pywt.wavedec(x[0], "db8", mode="periodization", level=3)
    d1 = coeffs[-1]
    assert d1.size == 75
    out = band_stats(x)[0]
    np.testing.assert_allclose(
        out[:5], [d1.mean(), d1.std(), d1.var(), stats.kurtosis(d1), stats.skew(d1)], rtol=1e-9
    )
    d3 = coeffs[1]  # 19 coefficients, level 3 of the same transform
    np.testing.assert_allclose(out[10], d3.mean(), rtol=1e-9, atol=1e-12)


def test_270_features_and_their_names():
    assert N_FEATURES == 270
    names = gesture_feature_names()
    assert len(names) == 270 == len(set(names))
    # 6 descriptors x (6 sequence stats + 7 bands x 5 stats + 4 mean-only bands)
    assert sum(n.startswith("cop_dist__") for n in names) == 45
    assert sum("_seq_" in n for n in names) == 36
    for name in ("cop_dist__seq_kurtosis", "max__d3_std", "n_above__a10_mean", "std__d7_skewness"):
        assert name in names
    assert "mean__d8_std" not in names


def test_gesture_features_concatenates_the_steps_per_descriptor(rng):
    frames = rng.random((150, 20, 20)) * 30
    f = gesture_features(frames, 50.0)
    assert f.shape == (270,)
    desc = frame_descriptors(upsample(frames))
    per = f.reshape(6, 45)
    np.testing.assert_allclose(per[:, :6], sequence_stats(desc))
    np.testing.assert_allclose(per[:, 6:], band_stats(desc))
    names = gesture_feature_names()
    assert names[45 * 3] == "cop_dist__seq_mean"
    assert f[45 * 3] == pytest.approx(desc[3].mean())


def test_short_gestures_are_padded_with_their_last_value(rng):
    frames = rng.random((100, 20, 20))
    padded = np.concatenate([frames, np.repeat(frames[-1:], 50, axis=0)])
    f_short, f_pad = gesture_features(frames), gesture_features(padded)
    assert np.all(np.isfinite(f_short))
    np.testing.assert_allclose(
        f_short.reshape(6, 45)[:, 6:], f_pad.reshape(6, 45)[:, 6:], rtol=1e-9, atol=1e-12
    )


def test_transformer_conventions_and_registry(rng):
    frames = rng.random((150, 20, 20))
    rec = recording_from_frames(frames, 50.0, {"label": "poke", "person": "p0"}, name="g0")
    est = make_features("gesture")
    assert isinstance(est, GestureFeatures)
    twin = clone(GestureFeatures(min_frames=140))
    assert twin.get_params() == {"min_frames": 140}
    X = est.fit_transform([rec, rec])
    assert X.shape == (2, 270)
    np.testing.assert_allclose(X[0], gesture_features(frames))
    assert list(est.get_feature_names_out()) == gesture_feature_names()


def test_taxel_order_of_the_channels_does_not_matter(rng):
    frames = rng.random((150, 4, 5))
    rec = recording_from_frames(frames, 50.0, {"label": "x"})
    perm = rng.permutation(20)
    shuffled = type(rec).from_arrays(
        rec.samples[:, perm], 50.0, [rec.channel_names[i] for i in perm], units="kPa"
    )
    X = GestureFeatures().fit_transform([rec, shuffled])
    np.testing.assert_array_equal(X[0], X[1])


def test_errors_name_the_recording_and_the_problem(rng):
    frames = rng.random((150, 3, 3))
    frames[5, 1, 1] = np.nan
    rec = recording_from_frames(frames, 50.0, {"label": "x"}, name="broken")
    with pytest.raises(ValueError, match=r"recording 'broken': frames hold 1 NaN/inf"):
        GestureFeatures().fit_transform([rec])
    odd = type(rec).from_arrays(np.ones((10, 1)), 50.0, ["fx"], units="kPa", name="odd")
    with pytest.raises(ValueError, match=r"'odd'.*'fx'.*not a taxel name"):
        GestureFeatures().fit_transform([odd])
    with pytest.raises(ValueError, match=r"frames must be \(time >= 2, rows, cols\)"):
        gesture_features(np.ones((150, 20)))
    with pytest.raises(ValueError, match="rate_hz must be positive"):
        gesture_features(np.ones((150, 2, 2)), 0.0)
