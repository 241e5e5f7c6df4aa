"""Classifiers, pipelines and evaluation protocols over lists of recordings.

A pipeline is ``features -> StandardScaler -> [LDA projection ->] classifier``, built by
:func:`make_pipeline` from the command-line names (:data:`CLASSIFIERS`,
``frictionfit.features.FEATURE_SETS``). :func:`evaluate` runs one protocol
(:data:`PROTOCOLS`) and pools the test predictions of all folds into accuracy,
macro-F1, a confusion matrix and per-condition breakdowns;
:func:`evaluate_incremental` adds one class at a time.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator, TransformerMixin, clone
from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
from sklearn.metrics import accuracy_score, confusion_matrix, f1_score
from sklearn.model_selection import LeaveOneGroupOut, StratifiedKFold, train_test_split
from sklearn.multiclass import OneVsRestClassifier
from sklearn.neighbors import KNeighborsClassifier
from sklearn.neural_network import MLPClassifier
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils.validation import check_is_fitted, validate_data

from frictionfit.calibration import (
    CalibratedPipeline,
    accuracy_at_coverage,
    calibrated_ece,
    expected_calibration_error,
    feature_draws,
    top_classes,
)
from frictionfit.errors import DatasetError
from frictionfit.features import make_features
from frictionfit.recording import Recording, within_rig
from frictionfit.transfer import RigTransfer

__all__ = [
    "CLASSIFIERS",
    "CONDITIONS",
    "PROJECTIONS",
    "DiscriminantProjection",
    "PROTOCOLS",
    "Evaluation",
    "SessionNormalised",
    "classes_of",
    "evaluate",
    "evaluate_incremental",
    "labels_of",
    "left_out_scores",
    "make_classifier",
    "make_pipeline",
    "projection_for",
    "splits",
]

#: Projections before the classifier (see :func:`make_pipeline`, :func:`projection_for`).
PROJECTIONS = ("auto", "lda", None)
CLASSIFIERS = ("svm-ovo", "svm-ova", "svm-poly", "svm-quadratic", "knn", "mlp")
#: Protocol name -> what it does (see :func:`splits`).
PROTOCOLS = {
    "kfold": "stratified 5-fold over all recordings (shuffled, seeded)",
    "mixed-5fold": "the same as kfold (the gesture papers' name: people mixed)",
    "person-dependent": "stratified 5-fold within each person, pooled",
    "holdout": "one stratified 80% / 20% split (baseline D's protocol)",
    "leave-one-session-out": "train on all sessions but one, test on it; every session",
    "leave-one-person-out": "the same, by person",
    "leave-one-repetition-out": "the same, by repetition",
    "leave-one-pressure-out": "the same, by pressure",
    "leave-one-rig-out": "the same, by metadata.rig: train on the other rigs, test on one; "
                         "calibrated, the held-out rig's probabilities tempered by the spread "
                         "between the training rigs (their sessions where one rig is left)",
}
#: Metadata keys reported per value in :attr:`Evaluation.breakdown` when present.
CONDITIONS = ("layers", "material", "session", "person", "repetition", "pressure", "speed",
              "rig")


def make_classifier(name: str = "svm-ovo", *, seed: int = 0, probability: bool = False):
    """A fresh classifier by its command-line name.

    ``svm-ovo``: RBF SVM, one-vs-one, ``gamma="scale"`` (kernel width from the data);
    ``svm-ova``: the same SVM one-vs-all; ``svm-poly``: cubic polynomial kernel;
    ``svm-quadratic``: quadratic kernel; ``knn``: distance-weighted 10 nearest
    neighbours; ``mlp``: a fully connected network (100 ReLU units, Adam, early stopping).
    All SVMs use ``C=10``; with ``probability=True`` they also give ``predict_proba``
    (libsvm's Platt scaling, fitted by an internal 5-fold split), which
    :class:`~frictionfit.calibration.CalibratedPipeline` then calibrates on held-out
    recordings; ``knn`` and ``mlp`` always give it.
    """
    def svc(**kw):
        if probability:  # scikit-learn >= 1.9 warns whenever the flag is given
            kw["probability"] = True
        return SVC(C=10.0, gamma="scale", random_state=seed, **kw)

    if name == "svm-ovo":
        return svc(kernel="rbf")  # libsvm trains one-vs-one; votes give the class
    if name == "svm-ova":
        return OneVsRestClassifier(svc(kernel="rbf"))
    if name == "svm-poly":
        return svc(kernel="poly", degree=3, coef0=1.0)
    if name == "svm-quadratic":
        return svc(kernel="poly", degree=2, coef0=1.0)
    if name == "knn":
        return KNeighborsClassifier(n_neighbors=10, weights="distance")
    if name == "mlp":
        return MLPClassifier(hidden_layer_sizes=(100,), max_iter=1000, early_stopping=True,
                             validation_fraction=0.15, n_iter_no_change=30, random_state=seed)
    raise ValueError(f"unknown classifier {name!r}; choose from {list(CLASSIFIERS)}")


def make_pipeline(features: str = "physical", classifier: str = "svm-ovo", *, seed: int = 0,
                  normalise_by: str | None = "session", project: str | None = None,
                  probability: bool = False, **feature_params) -> Pipeline:
    """``features -> StandardScaler -> [projection ->] classifier`` from command-line names.

    With ``normalise_by`` (default ``"session"``) the features are standardised
    within each session first (:class:`SessionNormalised`; a no-op for data
    without sessions). With ``project="lda"`` the scaled features are projected
    onto their linear discriminants (:class:`DiscriminantProjection`: at most
    ``n_classes - 1`` directions, whitened by the pooled within-class covariance;
    left out when the training data have too few rows to estimate it). The
    classifier's kernel then measures distances in units of the within-class
    scatter — repetitions, measurements and days of one material — instead of raw
    feature units. ``None`` (default) leaves the projection out;
    :func:`projection_for` chooses one for a dataset. ``probability``: see
    :func:`make_classifier`. ``feature_params`` go to the feature sets that take them.

    Examples
    --------
    >>> [name for name, _ in make_pipeline("handcrafted", "knn", project="lda").steps]
    ['features', 'scale', 'project', 'classifier']
    """
    feats = make_features(features, **feature_params)
    if normalise_by:
        feats = SessionNormalised(feats, key=normalise_by)
    steps = [("features", feats), ("scale", StandardScaler())]
    if project == "lda":
        steps.append(("project", DiscriminantProjection()))
    elif project is not None:
        raise ValueError(f"unknown projection {project!r}; choose 'lda' or None "
                         f"(projection_for resolves 'auto' for a dataset)")
    return Pipeline([*steps, ("classifier", make_classifier(classifier, seed=seed,
                                                            probability=probability))])


def projection_for(recordings: Sequence[Recording], project: str | None = "auto",
                   key: str = "session") -> str | None:
    """The projection ``make_pipeline`` gets; ``"auto"``: LDA when the data span several sessions.

    Recordings made on several days carry the day drift as within-class scatter,
    which the LDA projection learns to discount. Without sessions (FabricSlide slides,
    touch gestures) it is left out: the within-class scatter of the training pressures
    does not describe a new pressure.
    """
    if project != "auto":
        if project not in PROJECTIONS:
            raise ValueError(f"unknown projection {project!r}; choose from {PROJECTIONS}")
        return project
    sessions = {str(r.metadata[key]) for r in recordings if r.metadata.get(key) is not None}
    return "lda" if len(sessions) >= 2 else None


class DiscriminantProjection(TransformerMixin, BaseEstimator):
    """The linear discriminants of the training data, where there are enough rows for them.

    Fitted on ``n`` rows of ``p`` features in ``K`` classes, it projects onto the
    at most ``K - 1`` directions of linear discriminant analysis, whitened by the
    pooled within-class covariance (Ledoit-Wolf shrinkage). That covariance needs
    ``n - K > p`` degrees of freedom; with fewer rows (wide sets such as ``raw``, or
    a few recordings per class) the discriminants would only separate the training
    rows, so the features pass through unchanged (``lda_`` is None).
    """

    def fit(self, X, y) -> DiscriminantProjection:
        X, y = validate_data(self, X, y, dtype=np.float64)
        check_classification_targets(y)
        enough = X.shape[0] - np.unique(y).size > X.shape[1]
        self.lda_ = (LinearDiscriminantAnalysis(solver="eigen", shrinkage="auto").fit(X, y)
                     if enough else None)
        return self

    def transform(self, X) -> np.ndarray:
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        return X if self.lda_ is None else self.lda_.transform(X)


class SessionNormalised(TransformerMixin, BaseEstimator):
    """Features standardised within each recording session (day): a day-drift correction.

    Lab sessions differ by sensor offsets and gains, motor positions and material
    state, so every feature shifts and scales from day to day. This wrapper computes
    ``features`` and z-scores each feature within each value of ``metadata[key]`` of
    each rig (:func:`~frictionfit.recording.within_rig`),
    using only that session's own (unlabelled) recordings, at training and at
    prediction time alike: a session seen in training keeps its training
    statistics; a new session with at least ``min_group`` recordings in the
    ``transform`` call gets its own. A smaller new session (and recordings without
    ``key``) cannot be standardised by itself: it uses the mean of the training
    sessions' statistics instead (no correction of that day's drift) and a warning
    says so. Predictions for a whole new session are therefore best made in one
    call. When the training data have no sessions (e.g. gesture or FabricSlide
    data), the wrapper passes the features through unchanged.

    Parameters
    ----------
    features : transformer
        A feature set over recordings.
    key : str, default "session"
        The metadata key naming the session.
    min_group : int, default 10
        Fewest recordings of a session standardised by their own statistics.
    """

    def __init__(self, features, key: str = "session", min_group: int = 10):
        self.features = features
        self.key = key
        self.min_group = min_group

    def fit(self, X, y=None) -> SessionNormalised:
        self.fit_transform(X, y)
        return self

    def fit_transform(self, X, y=None, **fit_params) -> np.ndarray:
        X = list(X)
        self.features_ = clone(self.features)
        raw = self.features_.fit_transform(X, y)
        groups = self._groups(X)
        self.n_features_in_ = 1
        self.session_stats_ = {g: self._stats(raw[groups == g]) for g in set(groups)
                               if g is not None and (groups == g).sum() >= 2}
        self.active_ = bool(self.session_stats_)
        if not self.active_:  # no sessions in the training data: nothing to correct
            return raw
        self.mean_ = np.mean([m for m, _ in self.session_stats_.values()], axis=0)
        self.scale_ = np.mean([s for _, s in self.session_stats_.values()], axis=0)
        return self._normalised(raw, groups)

    def transform(self, X) -> np.ndarray:
        X = list(X)
        raw = self.features_.transform(X)
        return self._normalised(raw, self._groups(X)) if self.active_ else raw

    def transform_draws(self, X, n_draws: int, rng: np.random.Generator) -> np.ndarray:
        """Posterior draws of the features (see :func:`~frictionfit.calibration.feature_draws`),
        each standardised like :meth:`transform`; ``(n_draws, n, n_features)``."""
        X = list(X)
        draws = feature_draws(self.features_, X, n_draws, rng)
        if not self.active_:
            return draws
        groups = self._groups(X)
        normalised = [self._normalised(draws[0], groups)]
        with warnings.catch_warnings():  # its warning once per call, not once per draw
            warnings.simplefilter("ignore", UserWarning)
            normalised += [self._normalised(d, groups) for d in draws[1:]]
        return np.stack(normalised)

    def _groups(self, X) -> np.ndarray:
        """Each recording's group: its ``metadata[key]`` within its rig (``metadata.rig``),
        so that two rigs' sessions numbered alike stay two groups; None without the key."""
        out = np.empty(len(X), dtype=object)
        out[:] = [within_rig(r.metadata, self.key) for r in X]
        return out

    @staticmethod
    def _stats(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sd = x.std(axis=0)
        return x.mean(axis=0), np.where(sd > 0, sd, 1.0)

    def _normalised(self, raw: np.ndarray, groups: np.ndarray) -> np.ndarray:
        out = (raw - self.mean_) / self.scale_
        small = []
        for g in {g for g in groups if g is not None}:
            rows = groups == g
            if g in self.session_stats_:  # a training session: its training statistics
                mean, scale = self.session_stats_[g]
            elif rows.sum() >= self.min_group:  # a new session: its own statistics
                mean, scale = self._stats(raw[rows])
            else:
                small.append(g)
                continue
            out[rows] = (raw[rows] - mean) / scale
        if small or any(g is None for g in groups):
            warnings.warn(f"{self.key} {sorted(map(str, small))} (or recordings without "
                          f"{self.key!r}) have fewer than {self.min_group} recordings: "
                          "standardised with the training statistics, day drift uncorrected",
                          UserWarning, stacklevel=2)
        return out

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        return self.features_.get_feature_names_out()


def labels_of(recordings: Sequence[Recording], key: str = "label") -> np.ndarray:
    """``metadata[key]`` of every recording; DatasetError naming the first without it."""
    missing = [r.name for r in recordings if r.metadata.get(key) is None]
    if missing:
        raise DatasetError(f"recording {missing[0]!r} has no metadata {key!r} "
                           f"({len(missing)} of {len(recordings)} lack it)")
    return np.asarray([r.metadata[key] for r in recordings])


def classes_of(recordings: Sequence[Recording], key: str = "label") -> np.ndarray:
    """The classes to learn (:func:`labels_of`); DatasetError unless at least two differ."""
    y = labels_of(recordings, key)
    if np.unique(y.astype(str)).size < 2:
        raise DatasetError(f"a classifier needs at least two classes of {key!r}; all "
                           f"{len(y)} recordings are {str(y[0])!r}")
    return y


def splits(recordings: Sequence[Recording], protocol: str, y: np.ndarray, *,
           seed: int = 0, n_splits: int = 5) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """``(train_index, test_index)`` pairs of a protocol (see :data:`PROTOCOLS`)."""
    index = np.arange(len(recordings))
    y_codes = np.unique(y.astype(str), return_inverse=True)[1]
    if protocol in ("kfold", "mixed-5fold"):
        yield from _kfold(index, y_codes, n_splits, seed)
    elif protocol == "holdout":
        yield tuple(train_test_split(index, test_size=0.2, stratify=y_codes, random_state=seed))
    elif protocol == "person-dependent":
        people = labels_of(recordings, "person").astype(str)
        for person in np.unique(people):
            own = index[people == person]
            yield from _kfold(own, y_codes[own], n_splits, seed)
    elif protocol.startswith("leave-one-") and protocol.endswith("-out"):
        key = protocol.removeprefix("leave-one-").removesuffix("-out")
        groups = labels_of(recordings, key).astype(str)
        if key == "rig" and np.unique(groups).size < 2:
            raise DatasetError(
                f"protocol 'leave-one-rig-out' needs recordings of at least two rigs "
                f"(metadata.rig); all are of {np.unique(groups).tolist()}: evaluate the "
                "transfer to another rig with `frictionfit train` on this one and `frictionfit "
                "predict` on the other, or on simulated rigs (`frictionfit simulate --rig`)")
        if np.unique(groups).size < 2:
            raise DatasetError(f"protocol {protocol!r} needs at least two values of {key!r}, "
                               f"found {np.unique(groups).tolist()}")
        yield from LeaveOneGroupOut().split(index, y_codes, groups)
    else:
        raise ValueError(f"unknown protocol {protocol!r}; choose from {list(PROTOCOLS)}")


def _kfold(index, y_codes, n_splits, seed):
    smallest = np.bincount(y_codes).min() if y_codes.size else 0
    if smallest < 2:
        raise DatasetError(f"stratified {n_splits}-fold needs at least 2 recordings per class; "
                           f"the smallest class has {smallest}")
    cv = StratifiedKFold(n_splits=min(n_splits, smallest), shuffle=True, random_state=seed)
    for train, test in cv.split(index, y_codes):
        yield index[train], index[test]


@dataclass
class Evaluation:
    """Pooled test predictions of one protocol and their scores.

    Attributes
    ----------
    accuracy, macro_f1 : float
    confusion : DataFrame
        Counts, true labels as rows, predicted as columns.
    predictions : DataFrame
        One row per test recording: ``recording``, ``fold``, ``true``, ``predicted``, the
        metadata of :data:`CONDITIONS` present and, when calibrated, ``probability`` (of
        the predicted class) and the three most probable classes ``top1..3`` with
        ``p1..3`` (``top1`` can differ from ``predicted``: a doubtful call).
    breakdown : dict of str -> DataFrame
        Per condition key, accuracy and count per value.
    fold_accuracy : list of float
    probabilities : DataFrame or None
        Calibrated class probabilities, one row per row of ``predictions``, one column per
        class (classes absent from a fold's training data have probability 0).
    """

    accuracy: float
    macro_f1: float
    confusion: pd.DataFrame
    predictions: pd.DataFrame
    breakdown: dict[str, pd.DataFrame] = field(default_factory=dict)
    fold_accuracy: list[float] = field(default_factory=list)
    probabilities: pd.DataFrame | None = None

    def derived_accuracy(self, key: str, recordings: Sequence[Recording]) -> float:
        """Accuracy of a property of the label (e.g. ``layers``) read off the predicted label."""
        of_label = {r.metadata["label"]: r.metadata.get(key) for r in recordings}
        pred = self.predictions["predicted"].map(of_label)
        true = self.predictions["true"].map(of_label)
        return float(np.mean(pred.to_numpy() == true.to_numpy()))

    @property
    def correct(self) -> np.ndarray:
        """Per test recording, whether the prediction is right."""
        return (self.predictions["true"].astype(str)
                == self.predictions["predicted"].astype(str)).to_numpy()

    def calibration(self, coverage: float = 0.9, n_bins: int = 15) -> dict[str, float]:
        """``ece`` (top-class probability, ``n_bins`` bins), ``ece_if_calibrated`` (the
        median ECE of a calibrated classifier at these probabilities and this many
        recordings: :func:`~frictionfit.calibration.calibrated_ece`) and
        ``accuracy_at_<coverage>`` (on the most confident recordings); empty without
        probabilities."""
        if "probability" not in self.predictions:
            return {}
        conf = self.predictions["probability"].to_numpy()
        return {"ece": expected_calibration_error(conf, self.correct, n_bins),
                "ece_if_calibrated": calibrated_ece(conf, n_bins)[0],
                f"accuracy_at_{coverage:g}": accuracy_at_coverage(conf, self.correct, coverage)}


def evaluate(recordings: Sequence[Recording], features="physical", classifier: str = "svm-ovo",
             protocol: str = "kfold", *, target: str = "label", seed: int = 0,
             n_splits: int = 5, project: str | None = "auto",
             pipeline: Pipeline | None = None, calibrate: bool = True,
             n_draws: int = 32, feature_params: dict | None = None) -> Evaluation:
    """Train and test ``features -> scaler -> [projection ->] classifier``; pooled scores.

    Parameters
    ----------
    recordings : list of Recording
        Each with ``metadata[target]`` and the group key the protocol needs.
    features, classifier : str
        Command-line names (ignored when ``pipeline`` is given).
    project : {"auto", "lda", None}
        Projection before the classifier (:func:`projection_for` resolves ``"auto"``
        on all of ``recordings``).
    protocol : str
        One of :data:`PROTOCOLS`.
    target : str, default "label"
        The metadata key to predict (e.g. ``"layers"`` for the layer-count decision).
    pipeline : Pipeline, optional
        Cloned for every fold instead of building one from the names.
    calibrate : bool, default True
        Wrap each fold's pipeline in :class:`~frictionfit.calibration.CalibratedPipeline`
        (probabilities calibrated on held-out training recordings; averaged over
        ``n_draws`` feature draws where the features have them); ``probability``
        is then the calibrated probability of the predicted class.
    feature_params : dict, optional
        Keyword arguments of the feature sets that take them (e.g. ``relaxation=True``);
        ignored when ``pipeline`` is given.

    Examples
    --------
    >>> ev = evaluate(recs, "handcrafted", "knn", "leave-one-session-out")  # doctest: +SKIP
    >>> round(ev.accuracy, 3)  # doctest: +SKIP
    """
    recordings = list(recordings)
    y = classes_of(recordings, target)
    template = pipeline if pipeline is not None else make_pipeline(
        features, classifier, seed=seed, project=projection_for(recordings, project),
        probability=calibrate, **(feature_params or {}))
    if calibrate:
        template = CalibratedPipeline(template, n_draws=n_draws, seed=seed)
        if protocol == "leave-one-rig-out":  # the held-out rig is one the model never saw
            template = RigTransfer(template)
    rows, fold_acc, proba_rows = [], [], []
    for fold, (train, test) in enumerate(splits(recordings, protocol, y, seed=seed,
                                                n_splits=n_splits)):
        model = clone(template).fit([recordings[i] for i in train], y[train])
        tested = [recordings[i] for i in test]
        pred = model.predict(tested)
        if calibrate:
            proba_rows.append(pd.DataFrame(model.predict_proba(tested),
                                           columns=model.classes_.astype(str)))
        fold_acc.append(float(accuracy_score(y[test].astype(str), pred.astype(str))))
        for i, p in zip(test, pred, strict=True):
            rec = recordings[i]
            rows.append({"recording": rec.name, "fold": fold, "true": y[i], "predicted": p,
                         **{k: rec.metadata[k] for k in CONDITIONS if k in rec.metadata}})
    table = pd.DataFrame(rows)
    probabilities = None
    if calibrate:
        probabilities = pd.concat(proba_rows, ignore_index=True).fillna(0.0)
        probabilities = probabilities[sorted(probabilities.columns)]
        columns = list(probabilities.columns)
        called = [columns.index(str(p)) for p in table["predicted"]]
        table["probability"] = probabilities.to_numpy()[np.arange(len(table)), called]
        table = pd.concat([table, top_classes(probabilities.to_numpy(), columns)], axis=1)
    return _scored(table, fold_acc, probabilities)


def _scored(pred: pd.DataFrame, fold_acc: list[float],
            probabilities: pd.DataFrame | None = None) -> Evaluation:
    true, guess = pred["true"].astype(str), pred["predicted"].astype(str)
    labels = sorted(set(true) | set(guess))
    correct = true == guess
    breakdown = {
        key: pd.DataFrame({"accuracy": correct.groupby(pred[key]).mean(),
                           "n": correct.groupby(pred[key]).size()})
        for key in CONDITIONS if key in pred
    }
    return Evaluation(
        accuracy=float(correct.mean()),
        macro_f1=float(f1_score(true, guess, average="macro", labels=labels, zero_division=0)),
        confusion=pd.DataFrame(confusion_matrix(true, guess, labels=labels),
                               index=labels, columns=labels),
        predictions=pred, breakdown=breakdown, fold_accuracy=fold_acc,
        probabilities=probabilities,
    )


def left_out_scores(ev: Evaluation, key: str) -> pd.DataFrame:
    """Per value of ``key`` left out by a leave-one-``key``-out evaluation: its own scores.

    Returns
    -------
    DataFrame
        One row per left-out value, in order: ``key``, ``accuracy``, ``n`` (test
        recordings), ``trained_on`` (the other values: ``"lo-hi"`` when numeric, else a
        comma list) and ``where`` (``"below"``, ``"inside"`` or ``"above"`` the training
        values when numeric: extrapolation or interpolation; else ``""``).
    """
    if key not in ev.predictions:
        raise ValueError(f"the predictions have no {key!r} column; per left-out value "
                         f"scores need it (one of {list(CONDITIONS)})")
    values = pd.unique(ev.predictions[key])
    numeric = all(isinstance(v, (int, float, np.integer, np.floating)) for v in values)
    rows = []
    for value in (sorted(values) if numeric else values):
        test = (ev.predictions[key] == value).to_numpy()
        others = [v for v in values if v != value]
        row = {key: value, "accuracy": float(ev.correct[test].mean()), "n": int(test.sum())}
        if numeric and others:
            lo, hi = min(others), max(others)
            row["trained_on"] = f"{lo:g}" if lo == hi else f"{lo:g}-{hi:g}"
            row["where"] = "below" if value < lo else "above" if value > hi else "inside"
        else:
            row["trained_on"] = ",".join(map(str, others))
            row["where"] = ""
        rows.append(row)
    return pd.DataFrame(rows)


def evaluate_incremental(recordings: Sequence[Recording], features="spectral",
                         classifier: str = "knn", *, seed: int = 0, start: int = 2,
                         test_size: float = 0.5) -> pd.DataFrame:
    """The class-addition protocol: start with ``start`` classes, add one at a time.

    The recordings of every class are split once into train and test parts
    (stratified, ``test_size``). At each step the newly added class's training
    recordings update every pipeline step that has ``partial_fit`` (e.g. the
    incremental PCA of ``spectral``, the scaler); steps without it are refitted on
    all classes seen so far (the stateless feature sets, the classifier). The test
    recordings of the classes seen so far are then classified. Class order is a
    seeded shuffle.

    Returns
    -------
    DataFrame
        One row per step: ``n_classes``, ``added``, ``accuracy``, ``n_test``.
    """
    recordings = list(recordings)
    y = labels_of(recordings).astype(str)
    order = np.random.default_rng(seed).permutation(np.unique(y))
    if order.size <= start:
        raise DatasetError(f"the incremental protocol needs more than {start} classes, "
                           f"found {order.size}")
    train, test = train_test_split(np.arange(len(recordings)), test_size=test_size,
                                   stratify=y, random_state=seed)
    pipe = make_pipeline(features, classifier, seed=seed)
    *transformers, (_, clf) = pipe.steps
    rows = []
    for k in range(start, order.size + 1):
        seen, new = set(order[:k]), set(order[:k] if k == start else order[k - 1:k])
        seen_train = [i for i in train if y[i] in seen]
        new_train = [i for i in train if y[i] in new]
        x_seen: object = [recordings[i] for i in seen_train]
        x_new: object = [recordings[i] for i in new_train]
        for _, step in transformers:
            if hasattr(step, "partial_fit"):
                step.partial_fit(x_new)
            else:
                step.fit(x_seen)
            x_seen, x_new = step.transform(x_seen), step.transform(x_new)
        clf.fit(x_seen, y[seen_train])
        seen_test = [i for i in test if y[i] in seen]
        x_test: object = [recordings[i] for i in seen_test]
        for _, step in transformers:
            x_test = step.transform(x_test)
        acc = float(accuracy_score(y[seen_test], clf.predict(x_test)))
        rows.append({"n_classes": k, "added": ",".join(sorted(new)), "accuracy": acc,
                     "n_test": len(seen_test)})
    return pd.DataFrame(rows)
