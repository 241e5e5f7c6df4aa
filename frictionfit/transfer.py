"""A classifier that knows the rigs it was trained on, and is no surer than they allow elsewhere.

A rig is what ``metadata.rig`` names, with its declared stroke (``metadata.stroke_mm``)
and the sample rate: :func:`rig_key`. :class:`RigTransfer` wraps a calibrated classifier
(:class:`~frictionfit.calibration.CalibratedPipeline`): it records the training rigs
(``rigs_``) and estimates how much surer the classifier is than right on recordings of a
group it never saw: each group held out in turn (the rigs where there are two or more,
else the sessions: the spread between days of one rig is then the only evidence), the
held-out recordings' probabilities tempered by the inverse temperature that fits them
best (:class:`~frictionfit.calibration._Temperature`, never above 1). On a recording of a
rig it was not trained on, the probabilities are ``softmax(beta log p)`` with that
``shift_beta_``; on a training rig's recordings they are the classifier's own.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from scipy.special import softmax
from sklearn.base import BaseEstimator, ClassifierMixin, clone
from sklearn.model_selection import LeaveOneGroupOut
from sklearn.utils.validation import check_is_fitted

from frictionfit.calibration import CalibrationWarning, _Temperature
from frictionfit.recording import Recording

__all__ = ["RigTransfer", "describe_rig", "rig_key", "rigs_of", "unseen_rigs"]

#: Fewest groups (rigs, else sessions) for a held-out estimate of the shift.
MIN_GROUPS = 2


def rig_key(rec: Recording) -> tuple[str, float | None, float]:
    """``(rig name, declared stroke in mm or None, sample rate in Hz)`` of a recording (the
    name ``"unnamed"`` where ``metadata.rig`` is absent)."""
    rig = rec.rig
    return (rig.name or "unnamed", rig.stroke_mm, float(rec.sample_rate_hz))


def rigs_of(recordings: Sequence[Recording]) -> list[dict]:
    """One dict per rig of ``recordings`` (:func:`rig_key`): ``name``, ``stroke_mm``,
    ``sample_rate_hz``, ``n_recordings`` and ``sessions`` (sorted, as strings)."""
    out: dict[tuple, dict] = {}
    for rec in recordings:
        key = rig_key(rec)
        entry = out.setdefault(key, {"name": key[0], "stroke_mm": key[1],
                                     "sample_rate_hz": key[2], "n_recordings": 0,
                                     "sessions": set()})
        entry["n_recordings"] += 1
        entry["sessions"].add(str(rec.metadata.get("session")))
    return [dict(e, sessions=sorted(e["sessions"])) for e in out.values()]


def describe_rig(rig: dict) -> str:
    """``'name' (stroke 13 mm, 1000 Hz)`` of an entry of :func:`rigs_of`."""
    stroke = "stroke not declared" if rig["stroke_mm"] is None else \
        f"stroke {rig['stroke_mm']:g} mm"
    return f"{rig['name']!r} ({stroke}, {rig['sample_rate_hz']:g} Hz)"


def unseen_rigs(trained: Sequence[dict], recordings: Sequence[Recording]) -> list[str]:
    """One sentence per rig of ``recordings`` that is none of the ``trained`` rigs (entries
    of :func:`rigs_of`), saying how many recordings and what differs."""
    known = {(r["name"], r["stroke_mm"], r["sample_rate_hz"]) for r in trained}
    out = []
    for rig in rigs_of(recordings):
        if (rig["name"], rig["stroke_mm"], rig["sample_rate_hz"]) in known:
            continue
        diffs = []
        if rig["name"] not in {r["name"] for r in trained}:
            diffs.append("another rig")
        for key, what, unit in (("stroke_mm", "stroke", " mm"),
                                ("sample_rate_hz", "sample rate", " Hz")):
            seen = sorted({r[key] for r in trained}, key=str)
            if rig[key] not in seen:
                shown = ", ".join("undeclared" if v is None else f"{v:g}{unit}" for v in seen)
                diffs.append(f"{what} {'undeclared' if rig[key] is None else f'{rig[key]:g}'}"
                             f"{'' if rig[key] is None else unit} (trained: {shown})")
        out.append(f"{rig['n_recordings']} recording(s) of rig {describe_rig(rig)}, not one "
                   f"the model was trained on: {'; '.join(diffs)}")
    return out


class RigTransfer(ClassifierMixin, BaseEstimator):
    """A calibrated classifier whose probabilities on an unseen rig are tempered by the
    spread between the training rigs (or sessions).

    Parameters
    ----------
    model : estimator
        A classifier over lists of recordings with ``predict_proba`` (e.g.
        :class:`~frictionfit.calibration.CalibratedPipeline`); cloned, never changed.
    group_key : str, default "session"
        Metadata key of the groups held out where the training data have one rig.

    Attributes
    ----------
    model_ : estimator
        ``model`` fitted on all training recordings.
    rigs_ : list of dict
        The training rigs (:func:`rigs_of`).
    shift_beta_ : float
        Inverse temperature (<= 1) of the probabilities on an unseen rig; 1 where fewer than
        :data:`MIN_GROUPS` groups could be held out (a warning says so).
    shift_groups_ : str
        What was held out to estimate it: ``"rig"``, the ``group_key``, or ``"none"``.
    classes_ : ndarray of shape (n_classes,)
    """

    def __init__(self, model, group_key: str = "session"):
        self.model = model
        self.group_key = group_key

    def fit(self, X: Sequence[Recording], y) -> RigTransfer:
        X, y = list(X), np.asarray(y)
        self.rigs_ = rigs_of(X)
        self.model_ = clone(self.model).fit(X, y)
        self.classes_ = self.model_.classes_
        self.shift_groups_, groups = self._groups(X)
        self.shift_beta_ = 1.0
        if groups is None:
            warnings.warn("one rig and fewer than two sessions: the probabilities on another "
                          "rig are not tempered (nothing to estimate the shift from)",
                          UserWarning, stacklevel=2)
            return self
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", CalibrationWarning)
            scores = self._held_out_scores(X, y, groups)
        uncalibrated = [w for w in caught if issubclass(w.category, CalibrationWarning)]
        for w in caught:
            if w not in uncalibrated:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if uncalibrated:  # raw probabilities would size the shift of calibrated ones wrongly
            warnings.warn(f"the probabilities on another rig are not tempered: without one "
                          f"{self.shift_groups_} the model could not be calibrated "
                          f"({uncalibrated[0].message})", UserWarning, stacklevel=2)
            self.shift_groups_ = "none"
            return self
        beta = _Temperature().fit(scores, np.searchsorted(self.classes_, y)).beta_
        self.shift_beta_ = float(min(beta, 1.0))
        return self

    def _held_out_scores(self, X: list[Recording], y: np.ndarray,
                         groups: np.ndarray) -> np.ndarray:
        """Log-probabilities of each recording by a model trained without its group."""
        scores = np.empty((len(X), self.classes_.size))
        for train, test in LeaveOneGroupOut().split(np.arange(len(X)), y, groups):
            inner = clone(self.model).fit([X[i] for i in train], y[train])
            proba = np.zeros((test.size, self.classes_.size))
            proba[:, np.searchsorted(self.classes_, inner.classes_)] = inner.predict_proba(
                [X[i] for i in test])
            scores[test] = np.log(np.clip(proba, 1e-12, 1.0))
        return scores

    def _groups(self, X: list[Recording]) -> tuple[str, np.ndarray | None]:
        rigs = np.array([rig_key(r)[0] for r in X])
        if np.unique(rigs).size >= MIN_GROUPS:
            return "rig", rigs
        sessions = np.array([str(r.metadata.get(self.group_key)) for r in X])
        if np.unique(sessions).size >= MIN_GROUPS:
            return self.group_key, sessions
        return "none", None

    def seen(self, X: Sequence[Recording]) -> np.ndarray:
        """Per recording, whether its rig is one of the training rigs."""
        check_is_fitted(self, "rigs_")
        known = {(r["name"], r["stroke_mm"], r["sample_rate_hz"]) for r in self.rigs_}
        return np.array([rig_key(r) in known for r in X], dtype=bool)

    def predict_proba(self, X: Sequence[Recording]) -> np.ndarray:
        """Class probabilities: the model's on a training rig's recordings, tempered by
        ``shift_beta_`` on the others."""
        X = list(X)
        proba = self.model_.predict_proba(X)
        unseen = ~self.seen(X)
        if unseen.any() and self.shift_beta_ < 1.0:
            logp = np.log(np.clip(proba[unseen], 1e-12, 1.0))
            proba[unseen] = softmax(self.shift_beta_ * logp, axis=1)
        return proba

    def predict(self, X: Sequence[Recording]) -> np.ndarray:
        """The model's own call for each recording."""
        check_is_fitted(self, "model_")
        return self.model_.predict(list(X))
