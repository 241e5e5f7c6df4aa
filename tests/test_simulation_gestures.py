"""The synthetic gesture set: labelled as synthetic, deterministic, gesture-specific physics."""

from __future__ import annotations

import numpy as np
import pytest

from frictionfit.datasets.gesture_skin import frames_of, load
from frictionfit.features.touch import TOUCH_FEATURES, touch_features
from frictionfit.simulation.gestures import GESTURES, _person, render_gesture, simulate_gestures


@pytest.fixture(scope="module")
def small_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("gestures")
    paths = simulate_gestures(out, seed=3, people=2, repetitions=2,
                              gestures=("poke", "scratch"), progress=False)
    return out, paths


def test_files_metadata_and_frames(small_set):
    out, paths = small_set
    assert [p.name for p in paths] == [
        "p0_poke_00.npz", "p0_poke_01.npz", "p0_scratch_00.npz", "p0_scratch_01.npz",
        "p1_poke_00.npz", "p1_poke_01.npz", "p1_scratch_00.npz", "p1_scratch_01.npz",
    ]
    recs = load(out)
    assert len(recs) == 8
    for rec in recs:
        assert rec.metadata["synthetic"] is True
        assert "SYNTHETIC" in rec.metadata["source"]
        assert {"label", "person", "repetition", "gesture"} <= set(rec.metadata)
        assert rec.sample_rate_hz == 50.0 and rec.channels[0].unit == "kPa"
        f = frames_of(rec)
        assert f.shape == (150, 20, 20)
        assert np.isfinite(f).all() and f.min() >= 0 and f.max() <= 100
        assert f.max() > 5  # somebody touched it
        assert "repetition_hz" in rec.truth or rec.metadata["gesture"] == "poke"
    assert {r.metadata["person"] for r in recs} == {"p0", "p1"}


def test_deterministic_given_the_seed_and_independent_of_the_set_size(tmp_path, small_set):
    _, paths = small_set
    again = simulate_gestures(tmp_path / "a", seed=3, people=1, repetitions=1,
                              gestures=("scratch",), progress=False)
    np.testing.assert_array_equal(np.load(again[0])["frames"], np.load(paths[2])["frames"])
    other = simulate_gestures(tmp_path / "b", seed=4, people=1, repetitions=1,
                              gestures=("scratch",), progress=False)
    assert not np.array_equal(np.load(other[0])["frames"], np.load(paths[2])["frames"])


def test_bad_arguments_by_their_words(tmp_path):
    with pytest.raises(ValueError, match=r"unknown gesture\(s\) \['wave'\]"):
        simulate_gestures(tmp_path, gestures=("poke", "wave"), progress=False)
    with pytest.raises(ValueError, match="people and repetitions must be >= 1"):
        simulate_gestures(tmp_path, people=0, progress=False)


def test_gestures_differ_as_their_physics_says():
    person = _person(0, 1)
    f = {}
    for g in GESTURES:
        frames, truth = render_gesture(g, person, np.random.default_rng([9, GESTURES.index(g)]))
        f[g] = dict(zip(TOUCH_FEATURES, touch_features(frames, 50.0), strict=True))
        f[g]["truth"] = truth
    # a fingertip poke is small and short; a flat-hand press large and long
    assert f["poke"]["max_area_cm2"] < 0.3 * f["press"]["max_area_cm2"]
    assert f["poke"]["contact_s"] < 0.5 * f["press"]["contact_s"]
    # scratching repeats fast, in place; stroking sweeps far
    assert f["scratch"]["repetition_hz"] > 2.5
    assert f["stroke"]["cop_range_cm"] > 2 * f["scratch"]["cop_range_cm"]
    # pinch and grab converge
    assert f["pinch"]["spread_ratio"] < 0.7 and f["grab"]["spread_ratio"] < 1.0
    # a press relaxes after its peak; a slowly ramped push barely does
    assert f["press"]["relaxation_s"] > 0.1
    assert f["push"]["relaxation_s"] < 0.5 * f["press"]["relaxation_s"]


def test_people_differ_in_hand_size_and_habits():
    a, b = _person(0, 0), _person(0, 1)
    assert a["hand_scale"] != b["hand_scale"]
    assert a["habits"]["scratch"]["frequency"] != b["habits"]["scratch"]["frequency"]
    assert _person(0, 0) == a  # a person is the same every time


@pytest.mark.slow
def test_leave_one_person_out_is_harder_than_person_dependent(tmp_path):
    from sklearn.model_selection import (
        LeaveOneGroupOut,
        StratifiedKFold,
        cross_val_score,
    )
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC

    from frictionfit.features.wavelet import GestureFeatures

    simulate_gestures(tmp_path, seed=0, people=4, repetitions=10, progress=False)
    recs = load(tmp_path)
    X = GestureFeatures().fit_transform(recs)
    y = np.array([r.metadata["label"] for r in recs])
    g = np.array([r.metadata["person"] for r in recs])

    def svm():
        return make_pipeline(StandardScaler(), SVC(kernel="poly", degree=2))

    cv = StratifiedKFold(5, shuffle=True, random_state=0)
    dependent = np.mean([cross_val_score(svm(), X[g == p], y[g == p], cv=cv).mean()
                         for p in np.unique(g)])
    lopo = cross_val_score(svm(), X, y, groups=g, cv=LeaveOneGroupOut()).mean()
    assert dependent > 0.85
    assert lopo < dependent - 0.05
