"""Rigs in the model: which rigs a model saw, what differs on another, tempered probabilities."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.base import BaseEstimator, ClassifierMixin

from frictionfit.recording import Recording
from frictionfit.transfer import RigTransfer, rig_key, rigs_of, unseen_rigs


def _rec(label, session, rig="lab-a", stroke=13.0, rate=1000.0, x=0.0):
    metadata = {"label": label, "session": session, "rig": rig, "x": x}
    if stroke is not None:
        metadata["stroke_mm"] = stroke
    return Recording.from_arrays(np.zeros((4, 1)), rate, ["index_x"], metadata=metadata,
                                 name=f"{rig}_s{session}_{label}_{x:g}")


class _Nearest(ClassifierMixin, BaseEstimator):
    """Probabilities from a recording's ``metadata.x`` against each class's mean x (a stub
    classifier over recordings: sure where the classes are far apart)."""

    def __init__(self, sharpness: float = 20.0):
        self.sharpness = sharpness

    def fit(self, X, y):
        y = np.asarray(y)
        self.classes_ = np.unique(y)
        x = np.array([r.metadata["x"] for r in X])
        self.centres_ = np.array([x[y == c].mean() for c in self.classes_])
        return self

    def predict_proba(self, X):
        x = np.array([r.metadata["x"] for r in X])
        logits = -self.sharpness * (x[:, None] - self.centres_[None]) ** 2
        p = np.exp(logits - logits.max(axis=1, keepdims=True))
        return p / p.sum(axis=1, keepdims=True)

    def predict(self, X):
        return self.classes_[self.predict_proba(X).argmax(axis=1)]


def _sessions(shifts, rig="lab-a", **kw):
    """Two classes at x = 0 and 1, each session shifted by its own amount."""
    rng = np.random.default_rng(0)
    return [_rec(lab, s, rig, x=centre + shift + 0.05 * rng.standard_normal(), **kw)
            for s, shift in enumerate(shifts, start=1) for lab, centre in (("a", 0.0), ("b", 1.0))
            for _ in range(6)]


def test_rigs_are_named_with_their_stroke_and_rate():
    recs = [_rec("a", 1), _rec("b", 2), _rec("a", 6, "lab-b", 9.0, 500.0)]
    assert rig_key(recs[2]) == ("lab-b", 9.0, 500.0)
    assert rigs_of(recs) == [
        {"name": "lab-a", "stroke_mm": 13.0, "sample_rate_hz": 1000.0, "n_recordings": 2,
         "sessions": ["1", "2"]},
        {"name": "lab-b", "stroke_mm": 9.0, "sample_rate_hz": 500.0, "n_recordings": 1,
         "sessions": ["6"]}]
    notes = unseen_rigs(rigs_of(recs[:2]), recs)
    assert notes == ["1 recording(s) of rig 'lab-b' (stroke 9 mm, 500 Hz), not one the model "
                     "was trained on: another rig; stroke 9 mm (trained: 13 mm); sample rate "
                     "500 Hz (trained: 1000 Hz)"]
    assert unseen_rigs(rigs_of(recs[:2]), [_rec("a", 1, stroke=None)]) == [
        "1 recording(s) of rig 'lab-a' (stroke not declared, 1000 Hz), not one the model was "
        "trained on: stroke undeclared (trained: 13 mm)"]


def test_an_unseen_rig_is_no_surer_than_the_sessions_spread_allows():
    # sessions that shift the classes towards each other: a held-out session is often wrong
    train = _sessions([0.0, 0.35, -0.35])
    model = RigTransfer(_Nearest()).fit(train, [r.label for r in train])
    assert model.shift_groups_ == "session" and 0 < model.shift_beta_ < 1
    other = _sessions([0.3], rig="lab-b", stroke=9.0, rate=500.0)
    same = _sessions([0.3])
    assert not model.seen(other).any() and model.seen(same).all()
    p_other, p_same = model.predict_proba(other), model.predict_proba(same)
    np.testing.assert_allclose(p_same, model.model_.predict_proba(same))  # a known rig: as is
    assert (p_other.max(axis=1) <= p_same.max(axis=1) + 1e-12).all()
    assert p_other.max(axis=1).mean() < p_same.max(axis=1).mean() - 0.02
    np.testing.assert_array_equal(p_other.argmax(axis=1), p_same.argmax(axis=1))  # same calls
    np.testing.assert_allclose(p_other.sum(axis=1), 1.0)


def test_sessions_that_agree_leave_the_probabilities_as_they_are():
    # every held-out call right, and no surer (top ~0.95) than the rule of succession
    # allows for 36 right calls (37/38): the fitted temperature would sharpen; it is capped
    train = _sessions([0.0, 0.01, -0.01])
    model = RigTransfer(_Nearest(sharpness=3.0)).fit(train, [r.label for r in train])
    assert model.shift_beta_ == 1.0  # never sharpened
    other = _sessions([0.0], rig="lab-b")
    np.testing.assert_allclose(model.predict_proba(other), model.model_.predict_proba(other))


def test_two_training_rigs_hold_out_rigs_not_sessions():
    train = _sessions([0.0, 0.3]) + _sessions([-0.3], rig="lab-c", stroke=16.0)
    model = RigTransfer(_Nearest()).fit(train, [r.label for r in train])
    assert model.shift_groups_ == "rig" and len(model.rigs_) == 2


def test_one_session_of_one_rig_cannot_say_how_far_another_rig_is():
    train = _sessions([0.0])
    with pytest.warns(UserWarning, match="not tempered \\(nothing to estimate the shift"):
        model = RigTransfer(_Nearest()).fit(train, [r.label for r in train])
    assert model.shift_beta_ == 1.0 and model.shift_groups_ == "none"
