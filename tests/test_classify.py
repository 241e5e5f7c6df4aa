"""Classifiers, protocols, session standardisation and evaluation on tiny synthetic sets."""

from __future__ import annotations

import numpy as np
import pytest

from frictionfit.classify import (
    CLASSIFIERS,
    DiscriminantProjection,
    SessionNormalised,
    evaluate,
    evaluate_incremental,
    labels_of,
    make_classifier,
    make_pipeline,
    projection_for,
    splits,
)
from frictionfit.errors import DatasetError
from frictionfit.features.handcrafted import HandcraftedFeatures
from frictionfit.recording import Event, Recording

pytestmark = pytest.mark.usefixtures("feature_cache")

CHANNELS = ("thumb_x", "thumb_y", "index_x", "index_y")


def synthetic(label: int, session: int, trial: int, n_labels: int = 3) -> Recording:
    """A 2-motion recording whose peak height and relaxation depend on the class.

    Each session adds its own offset and gain (day drift); noise is seeded by the
    (label, session, trial) triple.
    """
    rng = np.random.default_rng([label, session, trial])
    t = np.arange(2000) / 1000.0
    peak, tau = 1.0 + label, 0.05 + 0.1 * label / n_labels
    out = np.where(t < 0.05, 0.0, np.where(t < 0.15, peak * (t - 0.05) / 0.1,
                                           0.5 * peak + 0.5 * peak * np.exp(-(t - 0.15) / tau)))
    motion = np.where(t < 1.05, out, out[1049] * np.exp(-(t - 1.05) / tau))
    x = np.concatenate([motion, motion, np.zeros(50)])
    gain, offset = 1.0 + 0.2 * session, 0.3 * session
    samples = np.stack([offset + gain * s * x for s in (1.0, 0.2, -0.8, 0.1)], axis=1)
    samples += rng.normal(0, 0.01, samples.shape)
    events = [Event(0.05 + 2 * k + dt, "move", tgt)
              for k in range(2) for dt, tgt in ((0.0, "p2"), (1.0, "p1"))]
    return Recording.from_arrays(
        samples, 1000.0, CHANNELS, events=events, name=f"s{session}_c{label}_{trial:02d}",
        metadata={"label": f"c{label}", "session": session, "trial": trial,
                  "layers": 1 + label % 2})


@pytest.fixture(scope="module")
def recordings():
    return [synthetic(c, s, k) for s in (1, 2, 3) for c in range(3) for k in range(4)]


@pytest.mark.parametrize("name", CLASSIFIERS)
def test_every_classifier_is_built(name):
    clf = make_classifier(name, seed=1)
    assert hasattr(clf, "fit") and hasattr(clf, "predict")


def test_unknown_names_are_refused_with_the_choices():
    with pytest.raises(ValueError, match="unknown classifier 'svm'.*svm-ovo"):
        make_classifier("svm")
    with pytest.raises(ValueError, match="unknown feature set 'phys'"):
        make_pipeline("phys")


def test_leave_one_session_out_holds_each_session_out_once(recordings):
    y = labels_of(recordings)
    folds = list(splits(recordings, "leave-one-session-out", y))
    assert len(folds) == 3
    for train, test in folds:
        test_sessions = {recordings[i].metadata["session"] for i in test}
        train_sessions = {recordings[i].metadata["session"] for i in train}
        assert len(test_sessions) == 1 and not test_sessions & train_sessions


def test_kfold_is_stratified_and_seeded(recordings):
    y = labels_of(recordings)
    a = [test.tolist() for _, test in splits(recordings, "kfold", y, seed=3)]
    b = [test.tolist() for _, test in splits(recordings, "kfold", y, seed=3)]
    assert a == b and len(a) == 5
    assert sorted(i for fold in a for i in fold) == list(range(len(recordings)))


def test_protocol_errors_name_the_problem(recordings):
    y = labels_of(recordings)
    with pytest.raises(DatasetError, match="has no metadata 'person'"):
        list(splits(recordings, "leave-one-person-out", y))
    with pytest.raises(ValueError, match="unknown protocol 'loso'"):
        list(splits(recordings, "loso", y))
    one_session = [r for r in recordings if r.metadata["session"] == 1]
    with pytest.raises(DatasetError, match="at least two values of 'session'"):
        list(splits(one_session, "leave-one-session-out", labels_of(one_session)))


def test_evaluate_scores_a_separable_set(recordings):
    ev = evaluate(recordings, "handcrafted", "knn", "leave-one-session-out",
                  pipeline=make_pipeline("handcrafted", "knn"))
    assert ev.accuracy == pytest.approx(1.0)
    assert ev.macro_f1 == pytest.approx(1.0)
    assert ev.confusion.to_numpy().trace() == len(recordings)
    assert set(ev.breakdown) >= {"session", "layers"}
    assert ev.breakdown["session"]["n"].sum() == len(recordings)
    assert ev.derived_accuracy("layers", recordings) == pytest.approx(1.0)
    assert len(ev.fold_accuracy) == 3


def test_auto_projection_is_lda_when_the_data_span_several_sessions(recordings):
    assert projection_for(recordings) == "lda"
    one_session = [r for r in recordings if r.metadata["session"] == 1]
    assert projection_for(one_session) is None
    assert projection_for(one_session, "lda") == "lda"
    assert projection_for(recordings, None) is None
    with pytest.raises(ValueError, match="unknown projection 'pca'"):
        projection_for(recordings, "pca")
    with pytest.raises(ValueError, match="unknown projection 'pca'"):
        make_pipeline("handcrafted", project="pca")


def test_discriminant_projection_needs_more_rows_than_features():
    rng = np.random.default_rng(0)
    y = np.repeat([0, 1, 2], 20)
    x = rng.normal(size=(60, 5)) + 3.0 * y[:, None] * np.array([1.0, 0, 0, 0, 0])
    proj = DiscriminantProjection().fit(x, y)
    assert proj.transform(x).shape == (60, 2)  # 3 classes -> 2 discriminant axes
    z = proj.transform(x)[:, 0]
    assert abs(np.corrcoef(z, y)[0, 1]) > 0.95  # the class direction comes first
    wide = rng.normal(size=(60, 58))  # 60 rows - 3 classes = 57 <= 58 features: pass through
    np.testing.assert_array_equal(DiscriminantProjection().fit(wide, y).transform(wide), wide)


def test_lda_projection_sits_between_scaler_and_classifier(recordings):
    y = labels_of(recordings)
    pipe = make_pipeline("handcrafted", "svm-ovo", project="lda").fit(recordings, y)
    assert [name for name, _ in pipe.steps] == ["features", "scale", "project", "classifier"]
    ev = evaluate(recordings, "handcrafted", "svm-ovo", "leave-one-session-out")  # auto: lda
    assert ev.accuracy == pytest.approx(1.0)


def test_evaluate_layers_as_target(recordings):
    ev = evaluate(recordings, protocol="kfold", target="layers",
                  pipeline=make_pipeline("handcrafted", "svm-ovo"))
    assert set(ev.confusion.index) == {"1", "2"}
    assert ev.accuracy > 0.75  # classes c0 and c2 share a layer count: a harder, binary task


def test_session_normalisation_removes_a_per_session_offset_and_gain(recordings):
    norm = SessionNormalised(HandcraftedFeatures(cache=False), min_group=5)
    x = norm.fit_transform(recordings)
    sessions = np.array([r.metadata["session"] for r in recordings])
    for s in (1, 2, 3):
        np.testing.assert_allclose(x[sessions == s].mean(axis=0), 0.0, atol=1e-9)
    # the sessions differ by an offset and a gain (and noise): after standardisation the
    # peak of one class agrees across sessions, before it does not
    j = list(norm.get_feature_names_out()).index("thumb_x:out_peak [N]")
    c0 = [i for i, r in enumerate(recordings) if r.label == "c0"]
    raw = HandcraftedFeatures(cache=False).fit_transform([recordings[i] for i in c0])[:, j]
    assert np.ptp(x[c0, j]) < 0.05 < 0.5 < np.ptp(raw)


def test_session_normalisation_keeps_two_rigs_sessions_apart(recordings):
    """Session 1 of rig A and session 1 of rig B (the same materials, another gain and
    offset) are two days: each is standardised by its own statistics."""
    def on(rig: str, gain: float, offset: float) -> list[Recording]:
        return [Recording.from_arrays(gain * r.samples + offset, 1000.0, CHANNELS,
                                      events=r.events, name=f"{rig}_{r.name}",
                                      metadata={**r.metadata, "rig": rig})
                for r in recordings if r.metadata["session"] == 1]
    both = on("A", 1.0, 0.0) + on("B", 1.7, 0.3)
    x = SessionNormalised(HandcraftedFeatures(cache=False), min_group=5).fit_transform(both)
    rigs = np.array([r.metadata["rig"] for r in both])
    for rig in ("A", "B"):
        np.testing.assert_allclose(x[rigs == rig].mean(axis=0), 0.0, atol=1e-9)


def test_session_normalisation_warns_on_a_small_session(recordings):
    norm = SessionNormalised(HandcraftedFeatures(cache=False), min_group=5).fit(recordings)
    with pytest.warns(UserWarning, match=r"session \['9'\].*fewer than 5 recordings"):
        x = norm.transform([synthetic(0, 9, 0), synthetic(1, 9, 0)])
    assert np.isfinite(x).all()
    # a few recordings of a training session keep that session's statistics, silently
    np.testing.assert_allclose(norm.transform(recordings[:2]), norm.transform(recordings)[:2])


def test_session_normalisation_is_a_no_op_without_sessions(recordings):
    bare = [Recording.from_arrays(r.samples, 1000.0, CHANNELS, events=r.events, name=r.name,
                                  metadata={"label": r.label}) for r in recordings[:6]]
    feats = HandcraftedFeatures(cache=False)
    norm = SessionNormalised(feats).fit(bare)
    np.testing.assert_allclose(norm.transform(bare), feats.fit_transform(bare))


def test_incremental_protocol_adds_one_class_per_step(recordings):
    table = evaluate_incremental(recordings, "handcrafted", "knn", start=2)
    assert table["n_classes"].tolist() == [2, 3]
    assert table["n_test"].tolist()[-1] == len(recordings) // 2
    assert (table["accuracy"] > 0.8).all()
    with pytest.raises(DatasetError, match="more than 3 classes"):
        evaluate_incremental(recordings, "handcrafted", "knn", start=3)
