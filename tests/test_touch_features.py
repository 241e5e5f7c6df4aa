"""Physical touch features against hand-computed values, and against simulated truth."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.base import clone

from frictionfit.datasets.gesture_skin import recording_from_frames
from frictionfit.features import make_features
from frictionfit.features.touch import TOUCH_FEATURES, TouchPhysicalFeatures, touch_features
from frictionfit.simulation.gestures import _person, render_gesture


def feats(frames, rate_hz=50.0, **kw):
    return dict(zip(TOUCH_FEATURES, touch_features(frames, rate_hz, **kw), strict=True))


def test_single_taxel_tap_by_hand():
    frames = np.zeros((10, 3, 3))
    frames[2:6, 1, 1] = 50.0  # 50 kPa on 1 cm² = 5 N, for 4 frames at 50 Hz
    f = feats(frames)
    assert f["peak_force_n"] == pytest.approx(5.0)
    assert f["contact_s"] == pytest.approx(0.08)
    assert f["max_area_cm2"] == pytest.approx(1.0)
    assert f["area_growth_cm2_s"] == pytest.approx(0.8 / 0.02)  # a one-frame step
    assert f["relaxation_s"] == 0.0  # flat hold: no relaxation
    assert f["cop_path_cm"] == 0.0 and f["cop_range_cm"] == pytest.approx(0.0, abs=1e-12)
    assert f["spread_ratio"] == pytest.approx(1.0)  # zero spread at both ends: defined as 1
    assert f["repetition_hz"] == 0.0  # fewer than 8 contact frames


def test_pitch_and_contact_threshold():
    frames = np.zeros((10, 3, 3))
    frames[2:6, 1, 1] = 50.0
    frames[2:6, 0, 0] = 1.5  # below the 2 kPa contact threshold: neither area nor force
    f = feats(frames, pitch_cm=2.0)
    assert f["peak_force_n"] == pytest.approx(20.0)  # 50 kPa x 4 cm² x 0.1
    assert f["max_area_cm2"] == pytest.approx(4.0)
    assert feats(frames, contact_kpa=1.0)["max_area_cm2"] == pytest.approx(2.0)


def test_area_growth_rate_by_hand():
    frames = np.zeros((10, 3, 3))
    for k in range(10):
        frames[k].flat[:k] = 10.0  # area 0, 1, ..., 9 cm²
    # 10 % of 9 reached at frame 1, 90 % (8.1) at frame 9: 0.8 x 9 cm² / (8 / 50 s)
    assert feats(frames)["area_growth_cm2_s"] == pytest.approx(0.8 * 9 / (8 / 50))


def test_relaxation_time_recovers_an_exponential():
    rate, tau = 100.0, 0.2
    t = np.arange(300) / rate
    force_kpa = np.where(t < 0.1, 0.0, 10.0 + 30.0 * np.exp(-(t - 0.1) / tau))
    force_kpa[t >= 2.5] = 0.0
    frames = np.zeros((300, 2, 2))
    frames[:, 0, 0] = force_kpa
    # plateau: where the force is flattest, just before release (30 e^-7.5 ~ 0.02 kPa high)
    assert feats(frames, rate)["relaxation_s"] == pytest.approx(tau, rel=0.02)
    frames[10:250, 0, 0] = 30.0
    assert feats(frames, rate)["relaxation_s"] == 0.0


def test_repetition_frequency_and_extent_of_an_oscillating_contact():
    rate, hz = 50.0, 3.0
    t = np.arange(100) / rate
    frames = np.zeros((100, 1, 2))
    frames[:, 0, 0] = 20.0 + 10.0 * np.sin(2 * np.pi * hz * t)
    frames[:, 0, 1] = 20.0 - 10.0 * np.sin(2 * np.pi * hz * t)
    # CoP x = 0.5 - 0.25 sin(...) cm: 3 Hz, extent 0.5 cm
    f = feats(frames, rate)
    assert f["repetition_hz"] == pytest.approx(hz, abs=rate / 512)
    assert f["cop_range_cm"] == pytest.approx(0.5, abs=0.01)
    assert f["peak_force_n"] == pytest.approx(4.0)  # 40 kPa over 1 cm², always


def test_cop_path_of_a_moving_fingertip():
    frames = np.zeros((5, 1, 5))
    for k in range(5):
        frames[k, 0, k] = 30.0  # one taxel (1 cm) further each frame
    f = feats(frames)
    assert f["cop_path_cm"] == pytest.approx(4.0)
    assert f["cop_range_cm"] == pytest.approx(4.0)


def test_spread_ratio_of_a_converging_pinch():
    frames = np.zeros((3, 1, 5))
    frames[0, 0, [0, 4]] = 10.0  # radius of gyration 2 cm, F = 2 N >= 0.2 x peak
    frames[2, 0, [1, 3]] = 20.0  # radius 1 cm at the force peak
    assert feats(frames)["spread_ratio"] == pytest.approx(0.5)


def test_untouched_recording_gives_zeros_never_nan():
    f = touch_features(np.full((20, 4, 4), 0.5), 50.0)
    np.testing.assert_array_equal(f, [0, 0, 0, 0, 0, 0, 0, 0, 1])


def test_known_truth_of_simulated_press_and_scratch():
    person = _person(0, 0)
    for rep in range(3):
        rng = np.random.default_rng([3, rep])
        frames, truth = render_gesture("press", person, rng)
        # the 30-ms sensor lag and the raised-cosine peak bias the estimate a little
        assert feats(frames)["relaxation_s"] == pytest.approx(truth["relaxation_s"], rel=0.25)
        frames, truth = render_gesture("scratch", person, rng)
        assert feats(frames)["repetition_hz"] == pytest.approx(truth["repetition_hz"], rel=0.1)
        frames, _ = render_gesture("pinch", person, rng)
        assert feats(frames)["spread_ratio"] < 0.7


def test_transformer_conventions_and_registry(rng):
    frames = rng.random((30, 5, 5)) * 10
    rec = recording_from_frames(frames, 50.0, {"label": "poke"}, name="g1")
    est = make_features("touch")
    assert isinstance(est, TouchPhysicalFeatures)
    twin = clone(TouchPhysicalFeatures(contact_kpa=3.0))
    assert twin.get_params()["contact_kpa"] == 3.0
    X = est.fit_transform([rec])
    np.testing.assert_allclose(X[0], touch_features(frames, 50.0))
    assert list(est.get_feature_names_out()) == list(TOUCH_FEATURES)


def test_errors_by_their_words():
    frames = np.zeros((5, 2, 2))
    frames[1, 0, 0] = np.inf
    rec = recording_from_frames(frames, 50.0, {"label": "x"}, name="bad")
    with pytest.raises(ValueError, match=r"recording 'bad': frames hold 1 NaN/inf"):
        TouchPhysicalFeatures().fit_transform([rec])
    with pytest.raises(ValueError, match=r"frames must be \(time, rows, cols\)"):
        touch_features(np.zeros((5, 4)), 50.0)
    with pytest.raises(ValueError, match="rate_hz must be positive"):
        touch_features(np.zeros((5, 2, 2)), -1.0)
