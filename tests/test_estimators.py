"""scikit-learn conventions of our feature sets, wrappers and classifiers."""

from __future__ import annotations

import re

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.pipeline import FeatureUnion
from sklearn.svm import SVC
from sklearn.utils.estimator_checks import parametrize_with_checks

from frictionfit.classify import (
    DiscriminantProjection,
    SessionNormalised,
    make_classifier,
    make_pipeline,
)
from frictionfit.features import make_features
from frictionfit.features.fftbins import FFTBinFeatures
from frictionfit.features.handcrafted import HandcraftedFeatures
from frictionfit.features.physical import FittedFeatures, PhysicalFeatures
from frictionfit.features.raw import RawSignalFeatures
from tests.test_features_rubbing import hand_built

RUBBING_SETS = [HandcraftedFeatures(cache=False), FFTBinFeatures(cache=False),
                RawSignalFeatures(n_samples=100, cache=False),
                PhysicalFeatures(fitted=False, cache=False)]


def _known_failures(estimator) -> dict:
    if isinstance(estimator, SVC):  # scikit-learn's own test suite marks these xfail for SVC
        why = "libsvm does not treat integer weights as repeated samples"
        return {"check_sample_weight_equivalence_on_dense_data": why,
                "check_sample_weight_equivalence_on_sparse_data": why}
    return {}


@parametrize_with_checks([make_classifier("svm-ovo"), make_classifier("knn"),
                          make_classifier("svm-quadratic")],
                         expected_failed_checks=_known_failures)
def test_classifiers_follow_the_sklearn_contract(estimator, check):
    check(estimator)


@parametrize_with_checks([DiscriminantProjection()])
def test_the_projection_follows_the_sklearn_contract(estimator, check):
    check(estimator)


@pytest.mark.parametrize("features", RUBBING_SETS, ids=lambda f: type(f).__name__)
def test_feature_sets_clone_and_name_their_features_with_units(features):
    twin = clone(features)
    assert twin.get_params() == features.get_params() and twin is not features
    names = features.fit([hand_built()]).get_feature_names_out()
    assert len(set(names)) == len(names)
    assert all(re.fullmatch(r"\w+:\w+(\.\d+)? \[[^\]]+\]", n) for n in names), names[:3]
    x = features.transform([hand_built(), hand_built("b", scale=(2.0, 1.0, 1.0, 1.0))])
    assert x.shape == (2, len(names)) and np.isfinite(x).all()


#: The sets that fit the contact law to each recording (whole fits: simulated measurements).
FITTED_SETS = [PhysicalFeatures(fitted=True, channels=("index_x", "index_y"), cache=False),
               FittedFeatures(channels=("index_x", "index_y"), cache=False)]


@pytest.fixture(scope="module")
def measurements():
    from frictionfit.simulation.measurements import simulate_measurements

    return simulate_measurements([(1, "paper-2", 1), (1, "carpet-1", 1)], seed=4)


@pytest.mark.parametrize("features", FITTED_SETS, ids=lambda f: type(f).__name__)
def test_fitted_feature_sets_clone_and_name_their_features_with_units(features, measurements):
    twin = clone(features)
    assert twin.get_params() == features.get_params() and twin is not features
    names = twin.fit(measurements[:1]).get_feature_names_out()
    assert len(set(names)) == len(names)
    assert all(re.fullmatch(r"\w+:\w+(\.\d+)? \[[^\]]+\]", n) for n in names), names[:3]
    assert any(":fit_k " in n for n in names)  # the fitted law's stiffness is among them
    x = twin.transform(measurements)
    assert x.shape == (2, len(names)) and np.isfinite(x).all()
    # transform does not depend on what else is in the batch (a recording's fit is its own)
    np.testing.assert_array_equal(twin.transform(measurements[1:]), x[1:])


def test_transform_before_fit_is_refused():
    with pytest.raises(Exception, match="not fitted"):
        HandcraftedFeatures(cache=False).transform([hand_built()])


def test_feature_sets_refuse_arrays_with_a_clear_message():
    with pytest.raises(TypeError, match="list of Recording objects, got ndarray"):
        HandcraftedFeatures(cache=False).fit([np.zeros(3)])


def test_a_comma_list_is_a_feature_union_with_prefixed_names():
    union = make_features("handcrafted,fftbins", cache=False)
    assert isinstance(union, FeatureUnion)
    names = union.fit([hand_built()]).get_feature_names_out()
    assert len(names) == 40 + 80 and names[0] == "handcrafted__thumb_x:out_peak [N]"


def test_pipeline_clones_and_exposes_feature_names():
    pipe = make_pipeline("handcrafted", "svm-quadratic", cache=False)
    twin = clone(pipe)
    assert twin.get_params()["classifier__degree"] == 2
    assert isinstance(twin.named_steps["features"], SessionNormalised)
    recs = [hand_built(f"r{i}", scale=(1.0 + i, 1.0, 1.0, 1.0)) for i in range(4)]
    for i, rec in enumerate(recs):
        rec.metadata["label"] = "ab"[i % 2]
    twin.fit(recs, [r.label for r in recs])
    assert twin[:-2].get_feature_names_out()[0] == "thumb_x:out_peak [N]"
    assert set(twin.predict(recs)) <= {"a", "b"}
