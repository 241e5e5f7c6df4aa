"""The lab stand-in (../shared/datasets/rubbing-lab, sessions 1-3): the headline comparison.

Slow (~4 min of feature extraction on two cores without a feature cache): run with
``-m slow``. Physical features must classify the 35 classes across days at least as
well as the published hand-crafted baseline, trained and tested the same way.
"""

from __future__ import annotations

import pytest

from frictionfit.classify import evaluate
from frictionfit.recording import read_dataset

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def lab(shared):
    return read_dataset(shared / "datasets" / "rubbing-lab")


def test_physical_features_match_the_handcrafted_baseline_across_sessions(lab):
    scores = {name: evaluate(lab, name, "svm-ovo", "leave-one-session-out").accuracy
              for name in ("physical", "handcrafted")}
    assert scores["physical"] >= scores["handcrafted"]
    assert scores["physical"] >= 0.93  # 0.948 measured; the held-back days may drift further
