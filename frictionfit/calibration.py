"""Class probabilities a lab can act on: calibrated, and optionally carrying each
recording's uncertainty.

:class:`CalibratedPipeline` wraps a classification pipeline (``features -> ... ->
classifier``). Its probabilities are the classifier's own (an SVM's Platt scaling;
decision values for a classifier without probabilities) mapped through a calibrator
(temperature scaling by default, its confidence bounded by the rule of succession)
fitted on *held-out* scores. By default each training recording is scored by
a pipeline trained on the other folds of a stratified split in which every fold holds a
share of every class in every session: the inner pipelines see every day and three
quarters or more of the recordings, so their scores are sized for the final pipeline.
Holding out whole sessions instead (``split="groups"``) trains each inner pipeline on
fewer days than the final one, and its probabilities come out too flat. With
``n_draws > 0`` and a feature set that can draw its rows (``transform_draws``: a
bootstrap over a recording's motions, values missing from a recording drawn from the
training values), the classifier's probabilities are averaged over the draws before
calibration, at training and prediction alike: a damaged recording, or one whose
motions disagree, gets a flatter distribution.

The scores of the calibration are in :func:`expected_calibration_error` (with
:func:`calibrated_ece`, what a calibrated classifier's would be on as many recordings),
:func:`reliability_table` and :func:`coverage_curve`; :func:`plot_reliability` draws
the reliability diagram and the accuracy-against-coverage curve.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy.optimize import brentq, minimize_scalar
from scipy.special import log_softmax, softmax
from sklearn.base import BaseEstimator, ClassifierMixin, clone
from sklearn.calibration import CalibratedClassifierCV
from sklearn.exceptions import NotFittedError
from sklearn.frozen import FrozenEstimator
from sklearn.model_selection import LeaveOneGroupOut, StratifiedKFold
from sklearn.pipeline import FeatureUnion, Pipeline
from sklearn.utils.validation import check_is_fitted

from frictionfit.recording import Recording

__all__ = [
    "CalibratedPipeline",
    "CalibrationWarning",
    "ECE_BINS",
    "SPLITS",
    "accuracy_at_coverage",
    "calibrated_ece",
    "coverage_curve",
    "expected_calibration_error",
    "feature_draws",
    "plot_reliability",
    "reliability_table",
    "top_classes",
]

#: Inner splits of :class:`CalibratedPipeline` (``split``).
SPLITS = ("stratified", "groups")
#: Equal-width confidence bins of the reliability table and the ECE.
ECE_BINS = 15
#: Fewest training recordings of a class for calibrated probabilities: with fewer, an
#: inner pipeline learns a class from one recording, its held-out probabilities are flat,
#: and the calibrator flattens every call to uniform (5 simulated classes, 3 recordings
#: each, k-fold: accuracy 1.000 at ECE 0.80; with 4 each, ECE 0.017).
MIN_PER_CLASS = 3
#: Range of the log inverse temperature of temperature scaling (scikit-learn's too).
LOG_BETA_BOUNDS = (-10.0, 10.0)


def feature_draws(transformer, X: Sequence[Recording], n_draws: int,
                  rng: np.random.Generator | int = 0) -> np.ndarray:
    """Feature rows drawn from the recordings' posteriors, shape ``(n_draws, n, n_features)``.

    A transformer with ``transform_draws(X, n_draws, rng)`` draws its own rows; a
    :class:`~sklearn.pipeline.FeatureUnion` concatenates its parts' draws; any other
    transformer has no posterior, and every draw is its ``transform(X)``. ``rng``: a
    generator or a seed.
    """
    rng = np.random.default_rng(rng)
    X = list(X)
    if hasattr(transformer, "transform_draws"):
        return np.asarray(transformer.transform_draws(X, n_draws, rng), dtype=np.float64)
    if isinstance(transformer, FeatureUnion):
        parts = [feature_draws(t, X, n_draws, rng) for _, t in transformer.transformer_list]
        return np.concatenate(parts, axis=-1)
    rows = np.asarray(transformer.transform(X), dtype=np.float64)
    return np.broadcast_to(rows, (n_draws, *rows.shape))


class CalibrationWarning(UserWarning):
    """The class probabilities could not be calibrated (see the message)."""


class _Scores(ClassifierMixin, BaseEstimator):
    """A classifier whose input already is its score matrix (to calibrate stored scores)."""

    def __init__(self, classes: Sequence = ()):
        self.classes = classes

    def fit(self, X, y=None) -> _Scores:
        self.classes_ = np.asarray(self.classes)
        return self

    def decision_function(self, X) -> np.ndarray:
        X = np.asarray(X, dtype=np.float64)
        return X[:, 1] - X[:, 0] if X.shape[1] == 2 else X  # binary: scikit-learn's 1-D form

    def predict(self, X) -> np.ndarray:
        return self.classes_[np.argmax(np.asarray(X, dtype=np.float64), axis=1)]


class _Temperature:
    """Temperature scaling of score matrices: probabilities ``softmax(beta_ * scores)``.

    ``beta_`` minimises the cross-entropy on the held-out rows (as scikit-learn's
    temperature scaling does), but no further than where the rows' mean top probability
    reaches ``(r + 1) / (n + 2)``, the rule of succession for ``r`` right calls of ``n``.
    Without that bound, a held-out set with no error drives the inverse temperature to
    its limit and every call to probability 1 (18 simulated recordings of 3 classes: 1.0,
    the others 1e-35); where the held-out calls have errors it seldom binds.
    """

    def fit(self, scores: np.ndarray, y: np.ndarray) -> _Temperature:
        """``scores`` (n, n_classes); ``y`` the index of each row's true class."""
        n = len(y)
        rows = np.arange(n)
        succession = (np.sum(scores.argmax(axis=1) == y) + 1) / (n + 2)

        def cross_entropy(log_beta: float) -> float:
            return -float(np.sum(log_softmax(np.exp(log_beta) * scores, axis=1)[rows, y]))

        def excess_confidence(log_beta: float) -> float:
            return softmax(np.exp(log_beta) * scores, axis=1).max(axis=1).mean() - succession

        log_beta = minimize_scalar(cross_entropy, bounds=LOG_BETA_BOUNDS, method="bounded").x
        if excess_confidence(log_beta) > 0 and excess_confidence(LOG_BETA_BOUNDS[0]) < 0:
            log_beta = brentq(excess_confidence, LOG_BETA_BOUNDS[0], log_beta)
        self.beta_ = float(np.exp(log_beta))
        return self

    def predict_proba(self, scores: np.ndarray) -> np.ndarray:
        return softmax(self.beta_ * np.asarray(scores, dtype=np.float64), axis=1)


class CalibratedPipeline(ClassifierMixin, BaseEstimator):
    """A classification pipeline with class probabilities calibrated on held-out sessions.

    Parameters
    ----------
    pipeline : Pipeline
        ``features -> ... -> classifier`` over lists of recordings (see
        :func:`frictionfit.classify.make_pipeline`); cloned, never changed.
    group_key : str, default "session"
        Metadata key of the groups (days) of the recordings.
    split : {"stratified", "groups"}, default "stratified"
        Which pipelines score the training recordings for the calibrator.
        ``"stratified"``: a stratified k-fold over the recordings (at most 5 folds, at
        most the smallest count of a class within a group), so every inner pipeline
        trains on a share of every class in every group, as the final pipeline does;
        where a class has a single recording in some group, stratified by class alone.
        ``"groups"``: each group scored by a pipeline trained on the other groups (the
        stratified split where there are fewer than two groups).
    method : {"temperature", "sigmoid", "isotonic"}, default "temperature"
        Temperature scaling keeps the classifier's ranking of classes and fits one
        number, its confidence bounded by the rule of succession (so a held-out set
        without errors does not make every call certain); the others are those of
        :class:`~sklearn.calibration.CalibratedClassifierCV`.
    n_draws : int, default 32
        Draws per recording when the feature set can draw them (one row is used where
        it cannot); 0: the feature rows themselves (point estimates). With draws, a
        damaged recording (missing samples, a motion cut short) gets a flatter
        distribution than its intact twin.
    seed : int, default 0

    Attributes
    ----------
    pipeline_ : Pipeline
        The pipeline refitted on all training recordings.
    calibrator_ : object or None
        Maps score matrices ``(n, n_classes)`` to probabilities; None where too few
        recordings could be held out (a :class:`CalibrationWarning` says so, and the
        probabilities are the classifier's own).
    classes_ : ndarray of shape (n_classes,)
    """

    def __init__(self, pipeline: Pipeline, group_key: str = "session",
                 split: str = "stratified", method: str = "temperature", n_draws: int = 32,
                 seed: int = 0):
        self.pipeline = pipeline
        self.group_key = group_key
        self.split = split
        self.method = method
        self.n_draws = n_draws
        self.seed = seed

    def fit(self, X: Sequence[Recording], y) -> CalibratedPipeline:
        X, y = list(X), np.asarray(y)
        if self.split not in SPLITS:
            raise ValueError(f"unknown split {self.split!r}; choose from {list(SPLITS)}")
        with warnings.catch_warnings():
            # libsvm's Platt scaling with pairwise coupling (SVC(probability=True)) ranks
            # correct calls better than temperature-scaled decision values; scikit-learn
            # 1.9 deprecates the flag in favour of CalibratedClassifierCV, which has no
            # pairwise coupling.
            warnings.filterwarnings("ignore", "The `probability` parameter was deprecated",
                                    FutureWarning)
            # A held-out group smaller than SessionNormalised's min_group is scored with the
            # training groups' statistics: expected inside calibration, not the user's data.
            warnings.filterwarnings("ignore", ".*standardised with the training statistics",
                                    UserWarning)
            self.pipeline_ = clone(self.pipeline).fit(X, y)
            self.classes_ = self.pipeline_.classes_
            try:
                held_out = np.empty((len(X), self.classes_.size))
                for train, test in self._splits(X, y):
                    model = clone(self.pipeline).fit([X[i] for i in train], y[train])
                    held_out[test] = self._scores(model, [X[i] for i in test])
                if self.method == "temperature":
                    self.calibrator_ = _Temperature().fit(
                        held_out, np.searchsorted(self.classes_, y))
                else:  # the frozen scorer is never refitted: its 2 folds partition the rows
                    self.calibrator_ = CalibratedClassifierCV(
                        FrozenEstimator(_Scores(self.classes_).fit(None)), method=self.method,
                        cv=2).fit(held_out, y)
            except NotFittedError:  # a bug, not a shortage of recordings
                raise
            except ValueError as exc:  # too few recordings to hold any out
                warnings.warn(f"class probabilities are not calibrated: {exc}",
                              CalibrationWarning, stacklevel=2)
                self.calibrator_ = None
        return self

    def _scores(self, model: Pipeline, X: list[Recording]) -> np.ndarray:
        """Scores ``(n, n_classes)`` in the order of ``classes_``: the log of the classifier's
        probabilities averaged over the feature draws (decision values averaged, for a
        classifier without probabilities); a class ``model`` never saw scores lowest."""
        if self.n_draws > 0:
            draws = feature_draws(model[0], X, self.n_draws, self.seed)
            if np.all(draws == draws[:1]):  # no posterior to carry: one evaluation
                draws = draws[:1]
        else:
            draws = model[0].transform(X)[None]
        rest = model[1:]
        if hasattr(rest, "predict_proba"):
            own = np.log(np.clip(np.mean([rest.predict_proba(d) for d in draws], axis=0),
                                 1e-12, 1.0))
        else:
            own = np.mean([rest.decision_function(d) for d in draws], axis=0)
            if own.ndim == 1:  # binary: one decision value d -> (-d/2, d/2)
                own = np.stack([-0.5 * own, 0.5 * own], axis=1)
        out = np.full((len(X), self.classes_.size), own.min() - 1.0 if own.size else 0.0)
        out[:, np.searchsorted(self.classes_, model.classes_)] = own
        return out

    def _splits(self, X, y) -> list:
        groups = np.asarray([str(r.metadata.get(self.group_key)) for r in X])
        index = np.arange(len(X))
        if self.split == "groups" and np.unique(groups).size >= 2:
            return list(LeaveOneGroupOut().split(index, y, groups))
        strata = np.char.add(np.char.add(y.astype(str), "\x1f"), groups)
        smallest = np.unique(strata, return_counts=True)[1].min()
        if smallest < MIN_PER_CLASS:  # too few of a class in some group
            strata = y.astype(str)
            smallest = np.unique(strata, return_counts=True)[1].min()
        if smallest < MIN_PER_CLASS:
            raise ValueError(f"calibration needs at least {MIN_PER_CLASS} recordings of every "
                             f"class (the smallest class has {smallest})")
        cv = StratifiedKFold(n_splits=min(5, smallest), shuffle=True, random_state=self.seed)
        return list(cv.split(index, strata))

    def predict_proba(self, X: Sequence[Recording]) -> np.ndarray:
        """Calibrated class probabilities, ``(n, n_classes)``; where the features have
        posterior draws, the classifier's probability is averaged over them first."""
        check_is_fitted(self, "pipeline_")
        scores = self._scores(self.pipeline_, list(X))
        if self.calibrator_ is not None:
            return self.calibrator_.predict_proba(scores)
        return softmax(scores, axis=1)  # uncalibrated (see the warning at fit)

    def predict(self, X: Sequence[Recording]) -> np.ndarray:
        """The pipeline's own call for each recording (an SVM's vote).

        As with scikit-learn's ``SVC(probability=True)``, the most probable class of
        :meth:`predict_proba` can differ from it (rarely: where the vote is close);
        on small training sets the probabilities' argmax was the worse call (12
        simulated classes, 3 recordings each: 0.458 against 0.569 for the vote).
        """
        check_is_fitted(self, "pipeline_")
        return self.pipeline_.predict(list(X))


def top_classes(proba: np.ndarray, classes: Sequence, k: int = 3) -> pd.DataFrame:
    """The ``k`` most probable classes per row: columns ``top1 .. topk`` and ``p1 .. pk``."""
    proba = np.asarray(proba)
    order = np.argsort(-proba, axis=1, kind="stable")[:, :k]
    classes = np.asarray(classes)
    out = {}
    for j in range(order.shape[1]):
        out[f"top{j + 1}"] = classes[order[:, j]]
        out[f"p{j + 1}"] = np.take_along_axis(proba, order[:, j:j + 1], axis=1)[:, 0]
    return pd.DataFrame(out)


def _bin_of(confidence: np.ndarray, n_bins: int) -> np.ndarray:
    """Index of each probability's equal-width bin of [0, 1] (edges in the lower bin)."""
    edges = np.linspace(0.0, 1.0, n_bins + 1)
    return np.clip(np.digitize(confidence, edges[1:-1], right=True), 0, n_bins - 1)


def reliability_table(confidence, correct, n_bins: int = ECE_BINS) -> pd.DataFrame:
    """Equal-width bins of the top-class probability: ``lo, hi, n, confidence, accuracy``."""
    confidence, correct = np.asarray(confidence, float), np.asarray(correct, float)
    edges = np.linspace(0.0, 1.0, n_bins + 1)
    which = _bin_of(confidence, n_bins)
    rows = []
    for b in range(n_bins):
        sel = which == b
        rows.append({"lo": edges[b], "hi": edges[b + 1], "n": int(sel.sum()),
                     "confidence": float(confidence[sel].mean()) if sel.any() else np.nan,
                     "accuracy": float(correct[sel].mean()) if sel.any() else np.nan})
    return pd.DataFrame(rows)


def expected_calibration_error(confidence, correct, n_bins: int = ECE_BINS) -> float:
    """ECE: the count-weighted mean of ``|accuracy - confidence|`` over equal-width bins."""
    table = reliability_table(confidence, correct, n_bins)
    used = table[table["n"] > 0]
    return float(np.sum(used["n"] * np.abs(used["accuracy"] - used["confidence"]))
                 / max(used["n"].sum(), 1))


def calibrated_ece(confidence, n_bins: int = ECE_BINS, n_draws: int = 4000,
                   seed: int = 0) -> tuple[float, float]:
    """The ECE that a perfectly calibrated classifier shows at these top-class probabilities:
    its median and 95th percentile over ``n_draws`` simulated outcomes, each call right with
    its own probability. An observed ECE within that range is what the number of
    recordings alone gives; ECE is biased upwards on few recordings."""
    confidence = np.asarray(confidence, float)
    if confidence.size == 0:
        return float("nan"), float("nan")
    right = np.random.default_rng(seed).random((n_draws, confidence.size)) < confidence
    in_bin = np.eye(n_bins)[_bin_of(confidence, n_bins)]  # (calls, bins), one-hot
    gap = (right - confidence) @ in_bin  # per draw and bin: sum of (right - probability)
    ece = np.abs(gap).sum(axis=1) / confidence.size
    return float(np.median(ece)), float(np.quantile(ece, 0.95))


def coverage_curve(confidence, correct) -> pd.DataFrame:
    """Accuracy on the most confident recordings: ``coverage, accuracy, threshold``, one row
    per count of recordings kept (most confident first)."""
    confidence, correct = np.asarray(confidence, float), np.asarray(correct, float)
    order = np.argsort(-confidence, kind="stable")
    kept = np.arange(1, order.size + 1)
    return pd.DataFrame({"coverage": kept / max(order.size, 1),
                         "accuracy": np.cumsum(correct[order]) / kept,
                         "threshold": confidence[order]})


def accuracy_at_coverage(confidence, correct, coverage: float = 0.9) -> float:
    """Accuracy on the ``coverage`` fraction of recordings with the highest confidence."""
    curve = coverage_curve(confidence, correct)
    n = max(int(np.ceil(coverage * len(curve))), 1)
    return float(curve["accuracy"].iloc[n - 1])


def plot_reliability(confidence, correct, path, title: str = "", n_bins: int = ECE_BINS) -> None:
    """PNG: the reliability diagram (accuracy against confidence per bin, with counts) and
    the accuracy against coverage."""
    from frictionfit._optional import pyplot

    plt = pyplot("The reliability diagram")

    table = reliability_table(confidence, correct, n_bins)
    curve = coverage_curve(confidence, correct)
    ece = expected_calibration_error(confidence, correct, n_bins)
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4.2))
    used = table[table["n"] > 0]
    width = 1.0 / n_bins
    left.bar(used["lo"], used["accuracy"], width=width, align="edge", color="tab:blue",
             alpha=0.7, edgecolor="white", label="accuracy in bin")
    left.plot([0, 1], [0, 1], color="0.4", linestyle="--", label="perfect calibration")
    left.hlines(used["confidence"], used["lo"], used["hi"], color="tab:red", linewidth=2,
                label="mean top-class probability in bin")
    for _, row in used.iterrows():
        left.annotate(str(int(row["n"])), (row["lo"] + width / 2, row["accuracy"]),
                      ha="center", va="bottom", fontsize=7, color="0.3")
    left.set(xlim=(0, 1), ylim=(0, 1.05), xlabel="top-class probability",
             ylabel="accuracy", title=f"reliability (ECE {ece:.3f}; calibrated on "
             f"{len(confidence)} recordings: {calibrated_ece(confidence, n_bins)[0]:.3f}; "
             f"{n_bins} bins)")
    left.legend(loc="upper left", fontsize=8)
    right.plot(curve["coverage"], curve["accuracy"], color="tab:green")
    right.axvline(0.9, color="0.6", linestyle=":", label="90 % coverage")
    right.set(xlim=(0, 1), ylim=(min(0.5, float(curve["accuracy"].min())), 1.01),
              xlabel="coverage (most confident first)", ylabel="accuracy",
              title="accuracy against coverage")
    right.legend(loc="lower left", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
