"""The base class of every feature set over a list of recordings, with a content cache.

A feature set turns each :class:`~frictionfit.recording.Recording` into one row of
named features. Subclasses write :meth:`RecordingFeatures._extract` (a batch of
recordings -> rows; batching lets expensive sets such as the physical fits run all
trials in one call) and :meth:`RecordingFeatures._names`. The base class gives
them the scikit-learn contract (``fit`` / ``transform`` / ``get_feature_names_out``)
and a per-recording cache: rows are stored with :class:`joblib.Memory` under
``$FRICTIONFIT_CACHE`` (default ``~/.cache/frictionfit``), keyed by the class, its
parameters and the recording's *content* (times, samples, channels, events,
metadata), so renaming or moving a file never recomputes and changing a single
sample always does. ``cache=False`` switches the cache off.
"""

from __future__ import annotations

import os
import warnings
import weakref
from collections.abc import Sequence
from pathlib import Path

import joblib
import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_is_fitted
from tqdm.auto import tqdm

from frictionfit.recording import Recording

__all__ = ["FeatureWarning", "RecordingFeatures", "cache_dir", "content_key"]

#: Bump when the meaning of cached rows changes for every feature set.
CACHE_VERSION = 1
_KEYS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def cache_dir() -> Path:
    """Where feature rows are cached: ``$FRICTIONFIT_CACHE`` or ``~/.cache/frictionfit``."""
    env = os.environ.get("FRICTIONFIT_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "frictionfit"


def content_key(rec: Recording) -> str:
    """A hash of everything a feature may read from ``rec`` (not its name or path)."""
    key = _KEYS.get(rec)
    if key is None:
        key = joblib.hash((
            rec.t, rec.samples, rec.sample_rate_hz,
            [(c.name, c.unit) for c in rec.channels],
            [(e.t, e.kind, e.target) for e in rec.events],
            sorted((str(k), repr(v)) for k, v in rec.metadata.items()),
        ))
        _KEYS[rec] = key
    return key


def _stored_row(extractor_key: str, recording_key: str, row=None):
    """The cached row of one recording; computed by the caller, handed in as ``row``."""
    return row


class RecordingFeatures(TransformerMixin, BaseEstimator):
    """A stateless feature set: a list of recordings -> ``X`` of shape (n_recordings, n_features).

    Subclasses implement ``_extract(recordings) -> ndarray (n, n_features)`` and
    ``_names() -> list[str]`` (readable names with units, e.g. ``"index_x:f_kin [N]"``).
    ``_extract`` may return NaN; subclasses that do must say so and either fill it
    in ``transform`` (see :class:`~frictionfit.features.physical.PhysicalFeatures`)
    or document it. Every constructor argument must be a parameter (scikit-learn
    rules), and a ``cache`` parameter (bool) turns the content cache on or off.

    **Missing values.** A recording whose features cannot be computed (too few
    motions, all samples of a channel lost, failed fits) gives NaN from ``_extract``;
    ``transform`` never returns NaN: it fills each such value with that feature's
    median over the recordings seen in ``fit`` (``fill_values_``; 0 when all were
    NaN) and emits a :class:`FeatureWarning` naming the feature and recordings.

    Attributes
    ----------
    fill_values_ : ndarray of shape (n_features,)
        Training median of each feature, used to fill values that cannot be computed.
    n_features_out_ : int
        Number of features.
    """

    #: Subclasses bump this when their rows change meaning, to invalidate the cache.
    _version = 1
    #: Recordings per batched extraction (None: all missing ones at once). A progress
    #: bar (on a terminal) counts the blocks, and each block is cached when done.
    _block: int | None = None
    cache: bool = True

    def _extract(self, recordings: Sequence[Recording]) -> np.ndarray:
        raise NotImplementedError

    def _names(self) -> list[str]:
        raise NotImplementedError

    def _extractor_key(self) -> str:
        params = {k: v for k, v in self.get_params(deep=False).items() if k != "cache"}
        cls = type(self)
        return joblib.hash((CACHE_VERSION, cls.__module__, cls.__qualname__, self._version,
                            sorted((k, repr(v)) for k, v in params.items()), self._names()))

    def _rows(self, recordings: Sequence[Recording]) -> np.ndarray:
        """Rows for ``recordings``: cached ones loaded, all missing ones extracted in one batch."""
        recordings = _as_list(recordings)
        n_out = len(self._names())
        if not self.cache:
            return self._checked(self._extract(recordings), len(recordings), n_out)
        memory = joblib.Memory(cache_dir() / "features", verbose=0)
        stored = memory.cache(_stored_row, ignore=["row"])
        ekey = self._extractor_key()
        keys = [content_key(r) for r in recordings]
        out = np.empty((len(recordings), n_out))
        missing = []
        for i, k in enumerate(keys):
            row = stored(ekey, k) if stored.check_call_in_cache(ekey, k) else None
            if row is not None and np.shape(row) == (n_out,):
                out[i] = row
            else:
                missing.append(i)
        blocks = [missing[i:i + (self._block or len(missing))]
                  for i in range(0, len(missing), self._block or max(len(missing), 1))]
        bar = tqdm(total=len(missing), desc=f"{type(self).__name__}", unit="recording",
                   disable=None if len(blocks) > 1 else True)
        for block in blocks:  # each block is one batched extraction, cached as soon as done
            rows = self._checked(self._extract([recordings[i] for i in block]),
                                 len(block), n_out)
            for i, row in zip(block, rows, strict=True):
                stored(ekey, keys[i], row=row)  # stores the row on a cache miss
                out[i] = row
            bar.update(len(block))
        bar.close()
        return out

    @staticmethod
    def _checked(x: np.ndarray, n_rows: int, n_out: int) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (n_rows, n_out):
            raise RuntimeError(f"feature extractor returned shape {x.shape}, "
                               f"expected ({n_rows}, {n_out})")
        return x

    def fit(self, X: Sequence[Recording], y=None) -> RecordingFeatures:
        """Learn the fill value of each feature: its median over ``X`` (0 where all are NaN)."""
        self._fit_rows(self._rows(X))
        return self

    def fit_transform(self, X: Sequence[Recording], y=None, **fit_params) -> np.ndarray:
        rows = self._rows(X)
        self._fit_rows(rows)
        return self._filled(rows, X)

    def _fit_rows(self, rows: np.ndarray) -> None:
        self.n_features_in_ = 1
        self.n_features_out_ = rows.shape[1]
        finite = np.isfinite(rows)
        counts = finite.sum(axis=0)
        medians = np.zeros(rows.shape[1])
        for j in np.flatnonzero(counts):
            medians[j] = np.median(rows[finite[:, j], j])
        self.fill_values_ = medians

    def transform(self, X: Sequence[Recording]) -> np.ndarray:
        """Features of each recording, shape (n_recordings, n_features), never NaN."""
        check_is_fitted(self, "fill_values_")
        return self._filled(self._rows(X), X)

    def _filled(self, rows: np.ndarray, X) -> np.ndarray:
        """Fill NaN (failed extractions) with the training medians, and say so."""
        bad = ~np.isfinite(rows)
        if bad.any():
            names = self._names()
            recs = [r.name for r in _as_list(X)]
            worst = [recs[i] for i in np.flatnonzero(bad.any(axis=1))[:3]]
            warnings.warn(
                f"{type(self).__name__}: {int(bad.sum())} of {bad.size} feature values could "
                f"not be computed (e.g. {names[int(np.flatnonzero(bad.any(axis=0))[0])]!r}; "
                f"recordings {worst}); filled with training medians",
                FeatureWarning, stacklevel=3,
            )
            rows = np.where(bad, self.fill_values_[None, :], rows)
        return rows

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        """Readable feature names with units."""
        return np.asarray(self._names(), dtype=object)


class FeatureWarning(UserWarning):
    """Some feature values could not be computed and were filled (see the message)."""


def _as_list(recordings) -> list[Recording]:
    recordings = list(recordings)
    bad = [type(r).__name__ for r in recordings if not isinstance(r, Recording)]
    if bad:
        raise TypeError(f"feature sets take a list of Recording objects, got {bad[0]}")
    return recordings
