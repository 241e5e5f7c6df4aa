"""Calibrated class probabilities: scores of calibration, the calibrated pipeline, draws."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.base import BaseEstimator, TransformerMixin

from frictionfit.calibration import (
    CalibratedPipeline,
    accuracy_at_coverage,
    calibrated_ece,
    coverage_curve,
    expected_calibration_error,
    feature_draws,
    plot_reliability,
    reliability_table,
    top_classes,
)
from frictionfit.classify import evaluate, make_pipeline
from frictionfit.recording import Recording

pytestmark = pytest.mark.usefixtures("feature_cache")


def test_ece_is_zero_when_confidence_equals_accuracy_and_the_gap_otherwise():
    conf = np.full(100, 0.75)
    correct = np.arange(100) < 75
    assert expected_calibration_error(conf, correct) == pytest.approx(0.0)
    # overconfident: 0.9 claimed, half right -> a gap of 0.4 in the only bin used
    assert expected_calibration_error(np.full(10, 0.9), np.arange(10) < 5) == pytest.approx(0.4)
    # two bins weighted by count: 0.3 (n=2) and 0.1 (n=8) -> 0.14
    conf = np.r_[0.2, 0.2, np.full(8, 0.9)]
    correct = np.r_[True, False, np.full(8, True)]
    assert expected_calibration_error(conf, correct) == pytest.approx((2 * 0.3 + 8 * 0.1) / 10)
    table = reliability_table(conf, correct, n_bins=15)
    assert table["n"].sum() == 10 and len(table) == 15


def test_calibrated_ece_is_what_calibrated_calls_show_and_shrinks_with_their_number():
    rng = np.random.default_rng(3)
    conf = rng.uniform(0.4, 1.0, 70)
    median, high = calibrated_ece(conf)
    # outcomes drawn right with their own probability: calibrated by construction
    seen = [expected_calibration_error(conf, rng.random(conf.size) < conf) for _ in range(400)]
    assert median == pytest.approx(np.median(seen), abs=0.01)
    assert np.mean(np.array(seen) <= high) == pytest.approx(0.95, abs=0.03)
    # an overconfident classifier (right half the time at 0.7-1.0) lies far above the range
    over = rng.uniform(0.7, 1.0, 70)
    assert expected_calibration_error(over, np.arange(70) % 2 == 0) > calibrated_ece(over)[1]
    assert calibrated_ece(np.tile(conf, 8))[0] < median / 2  # 8x the calls: ~1/sqrt(8)
    assert calibrated_ece(conf, seed=1) != calibrated_ece(conf, seed=2)
    assert calibrated_ece(conf) == calibrated_ece(conf)
    assert all(np.isnan(calibrated_ece([])))


def test_coverage_curve_keeps_the_most_confident_first():
    conf = np.array([0.9, 0.2, 0.8, 0.5])
    correct = np.array([True, False, True, False])
    curve = coverage_curve(conf, correct)
    assert curve["coverage"].tolist() == [0.25, 0.5, 0.75, 1.0]
    assert curve["accuracy"].tolist() == [1.0, 1.0, pytest.approx(2 / 3), 0.5]
    assert accuracy_at_coverage(conf, correct, 0.5) == 1.0
    assert accuracy_at_coverage(conf, correct, 0.9) == 0.5  # ceil(0.9 * 4) = 4 kept


def test_top_classes_orders_by_probability():
    top = top_classes(np.array([[0.1, 0.7, 0.2], [0.5, 0.2, 0.3]]), ["a", "b", "c"], k=3)
    assert top["top1"].tolist() == ["b", "a"] and top["top3"].tolist() == ["a", "b"]
    assert top["p1"].tolist() == [0.7, 0.5] and top["p2"].tolist() == [0.2, 0.3]


def synthetic(label: int, session: int, trial: int, spread: float) -> Recording:
    """Two channels whose level depends on the class, with session offsets and noise."""
    rng = np.random.default_rng([label, session, trial])
    level = label + rng.normal(0.0, spread) + 0.2 * session
    samples = level + rng.normal(0.0, 0.01, (200, 2))
    return Recording.from_arrays(samples, 100.0, ("a", "b"), name=f"s{session}_{label}_{trial}",
                                 metadata={"label": f"c{label}", "session": session})


class LevelFeatures(TransformerMixin, BaseEstimator):
    """Channel means; ``transform_draws`` widens the draws of recordings named in ``wide``."""

    def __init__(self, wide: tuple[str, ...] = ()):
        self.wide = wide

    def fit(self, X, y=None):
        return self

    def transform(self, X):
        return np.array([r.samples.mean(axis=0) for r in X])

    def transform_draws(self, X, n_draws, rng):
        rows = self.transform(X)
        sd = np.array([1.0 if r.name in self.wide else 1e-6 for r in X])[:, None]
        return rows + sd * rng.normal(size=(n_draws, *rows.shape))

    def get_feature_names_out(self, input_features=None):
        return np.array(["a [N]", "b [N]"], dtype=object)


def _pipeline(wide=(), probability=True):
    from sklearn.pipeline import Pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC

    svc = SVC(random_state=0, **({"probability": True} if probability else {}))
    return Pipeline([("features", LevelFeatures(wide)), ("scale", StandardScaler()),
                     ("classifier", svc)])


@pytest.fixture(scope="module")
def overlapping():
    """Three classes whose levels overlap (spread 0.45 for steps of 1): not all separable."""
    return [synthetic(c, s, k, 0.45) for s in (1, 2, 3) for c in range(3) for k in range(8)]


def test_calibrated_pipeline_gives_probabilities_that_agree_with_its_predictions(overlapping):
    train = [r for r in overlapping if r.metadata["session"] != 3]
    test = [r for r in overlapping if r.metadata["session"] == 3]
    y = np.array([r.metadata["label"] for r in train])
    model = CalibratedPipeline(_pipeline()).fit(train, y)
    proba = model.predict_proba(test)
    assert proba.shape == (len(test), 3)
    np.testing.assert_allclose(proba.sum(axis=1), 1.0)
    # the call is the SVM's vote; its probabilities agree with it on nearly every recording
    assert np.mean(model.predict(test) == model.classes_[proba.argmax(axis=1)]) >= 0.9
    # overlapping classes: the calibrated model is not sure of everything
    assert 0.4 < proba.max(axis=1).mean() < 0.99


def test_a_held_out_set_without_errors_does_not_make_every_call_certain():
    # three classes far apart (spread 0.01 for steps of 1), six training recordings each
    recs = [synthetic(c, s, k, 0.01) for s in (1, 2) for c in range(3) for k in range(3)]
    train = [r for r in recs if r.name.endswith(("_0", "_1"))]
    test = [r for r in recs if r.name.endswith("_2")]
    y = np.array([r.metadata["label"] for r in train])
    model = CalibratedPipeline(_pipeline()).fit(train, y)
    top = model.predict_proba(test).max(axis=1)
    assert np.all(model.predict(test) == [r.metadata["label"] for r in test])
    # 12 held out, 12 right: about (12 + 1) / (12 + 2) for the next, not 1 - 1e-30
    assert np.all(top < 0.999) and top.mean() > 0.85


def test_temperature_matches_the_rule_of_succession_on_separated_scores():
    from frictionfit.calibration import _Temperature

    rng = np.random.default_rng(0)
    y = np.repeat(np.arange(4), 10)
    scores = np.eye(4)[y] * 3.0 + rng.normal(0, 0.1, (40, 4))
    proba = _Temperature().fit(scores, y).predict_proba(scores)
    assert proba[np.arange(40), y].mean() == pytest.approx(1 - 1 / 42, abs=0.01)


def test_wide_posterior_draws_flatten_the_probabilities(overlapping):
    train = [r for r in overlapping if r.metadata["session"] != 3]
    test = [r for r in overlapping if r.metadata["session"] == 3]
    y = np.array([r.metadata["label"] for r in train])
    sure = CalibratedPipeline(_pipeline(), n_draws=64).fit(train, y)
    wide_names = tuple(r.name for r in test)
    unsure = CalibratedPipeline(_pipeline(wide=wide_names), n_draws=64).fit(train, y)
    p_sure = sure.predict_proba(test).max(axis=1)
    p_unsure = unsure.predict_proba(test).max(axis=1)
    assert np.mean(p_unsure < p_sure) >= 0.9


def test_feature_draws_repeat_a_transformer_without_a_posterior(overlapping):
    from sklearn.pipeline import FeatureUnion

    union = FeatureUnion([("a", LevelFeatures()), ("b", LevelFeatures(wide=("s1_0_0",)))])
    union.fit(overlapping[:3])
    draws = feature_draws(union, overlapping[:3], 5, rng=0)
    assert draws.shape == (5, 3, 4)
    assert np.ptp(draws[:, 0, 2]) > 0.1 and np.ptp(draws[:, 1, 2]) < 1e-4


def test_evaluate_reports_probabilities_top3_and_calibration_scores(overlapping, tmp_path):
    ev = evaluate(overlapping, protocol="leave-one-session-out", pipeline=_pipeline())
    assert {"probability", "top1", "p1", "top3", "p3"} <= set(ev.predictions.columns)
    assert np.mean(ev.predictions["predicted"] == ev.predictions["top1"]) >= 0.9
    assert (ev.predictions["probability"] <= ev.predictions["p1"] + 1e-12).all()
    assert ev.probabilities.shape == (len(overlapping), 3)
    scores = ev.calibration()
    assert set(scores) == {"ece", "ece_if_calibrated", "accuracy_at_0.9"}
    assert 0.0 <= scores["ece"] <= 1.0
    assert scores["ece_if_calibrated"] == calibrated_ece(ev.predictions["probability"])[0]
    plot_reliability(ev.predictions["probability"], ev.correct, tmp_path / "r.png", "t")
    assert (tmp_path / "r.png").stat().st_size > 10_000
    plain = evaluate(overlapping, protocol="leave-one-session-out",
                     pipeline=_pipeline(probability=False), calibrate=False)
    assert "probability" not in plain.predictions and plain.calibration() == {}


def test_make_pipeline_svm_gives_probabilities_on_request():
    assert hasattr(make_pipeline("handcrafted", "svm-ovo", probability=True), "predict_proba")
    assert not hasattr(make_pipeline("handcrafted", "svm-ovo"), "predict_proba")


def _damaged(rec: Recording, seed: int, how: str) -> Recording:
    """``rec`` with 30 % of its samples lost in bursts of 20-200 (``"gaps"``), or with the
    back stroke of one of its analysed motions lost (``"cut"``)."""
    rng = np.random.default_rng(seed)
    samples, t = rec.samples.copy(), rec.t
    if how == "gaps":
        gone = np.zeros(t.size, dtype=bool)
        while gone.mean() < 0.3:
            start = rng.integers(0, t.size)
            gone[start:start + rng.integers(20, 200)] = True
    else:
        k = 1 + rng.integers(0, 4)
        gone = (t > 1.05 + 2 * k) & (t < 2.0 + 2 * k)
    samples[gone] = np.nan
    return Recording.from_arrays(samples, rec.sample_rate_hz, rec.channel_names,
                                 events=rec.events, name=f"{rec.name}_{how}",
                                 metadata=rec.metadata)


def test_a_damaged_recording_is_called_with_less_confidence_than_its_intact_twin():
    from frictionfit.simulation.materials import CLASSES
    from frictionfit.simulation.measurements import simulate_measurements

    labels = list(CLASSES)[:8]
    specs = [(s, lab, k) for s in (1, 2, 3) for lab in labels for k in (1, 2, 3, 4)]
    recs = simulate_measurements(specs, seed=2, pad_to=len(specs))
    train = [r for r in recs if r.metadata["session"] != 3]
    test = [r for r in recs if r.metadata["session"] == 3]
    y = np.array([r.metadata["label"] for r in train])
    model = CalibratedPipeline(make_pipeline("physical", probability=True),
                               n_draws=32).fit(train, y)
    clean = model.predict_proba(test).max(axis=1)
    for how, share in (("gaps", 0.9), ("cut", 0.8)):
        # each damaged twin is predicted within its otherwise intact session
        damaged = np.array([
            model.predict_proba([*test[:i], _damaged(test[i], i, how), *test[i + 1:]])[i].max()
            for i in range(len(test))])
        # measured on three simulated sets: gaps 0.906-1.0, cut 0.875-0.979 (docs/decisions.md)
        assert np.mean(damaged < clean) >= share, how


def test_stratified_calibration_folds_hold_every_class_of_every_session(overlapping):
    y = np.array([r.metadata["label"] for r in overlapping])
    sessions = np.array([r.metadata["session"] for r in overlapping])
    model = CalibratedPipeline(_pipeline())
    folds = model._splits(overlapping, y)
    assert len(folds) == 5  # 8 recordings of each class in each session: 5 folds
    for train, test in folds:
        assert np.intersect1d(train, test).size == 0
        # every inner pipeline trains on every class of every session, as the final one
        assert len({(a, b) for a, b in zip(y[train], sessions[train], strict=True)}) == 9
    held = np.sort(np.concatenate([test for _, test in folds]))
    np.testing.assert_array_equal(held, np.arange(len(overlapping)))
    by_group = CalibratedPipeline(_pipeline(), split="groups")._splits(overlapping, y)
    assert [set(sessions[test]) for _, test in by_group] == [{1}, {2}, {3}]


def test_stratified_calibration_falls_back_to_classes_and_rejects_unknown_splits(overlapping):
    one_each = [r for r in overlapping if r.metadata["session"] == 1 or r.name.endswith("_0")]
    y = np.array([r.metadata["label"] for r in one_each])
    folds = CalibratedPipeline(_pipeline())._splits(one_each, y)
    assert len(folds) == 5  # sessions 2-3 hold one recording per class: by class alone
    with pytest.raises(ValueError, match="unknown split 'days'"):
        CalibratedPipeline(_pipeline(), split="days").fit(overlapping, np.array(
            [r.metadata["label"] for r in overlapping]))


def test_too_few_recordings_of_a_class_are_left_uncalibrated_and_said(overlapping):
    from frictionfit.calibration import MIN_PER_CLASS, CalibrationWarning

    # fewer than MIN_PER_CLASS of a class: its inner pipelines would learn it from one
    # recording, and the calibrator would flatten every call to uniform
    few = [r for r in overlapping if r.metadata["session"] == 1
           and int(r.name.rsplit("_", 1)[1]) < MIN_PER_CLASS - 1]
    y = np.array([r.metadata["label"] for r in few])
    with pytest.warns(CalibrationWarning, match=f"needs at least {MIN_PER_CLASS} recordings "
                                                 "of every class"):
        model = CalibratedPipeline(_pipeline(), n_draws=0).fit(few, y)
    assert model.calibrator_ is None
    np.testing.assert_allclose(model.predict_proba(few).sum(axis=1), 1.0)
