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
import weakref
from collections.abc import Sequence
from pathlib import Path

import joblib
import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_is_fitted

from frictionfit.recording import Recording

__all__ = ["RecordingFeatures", "cache_dir", "content_key"]

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
    """

    #: Subclasses bump this when their rows change meaning, to invalidate the cache.
    _version = 1
    cache: bool = True

    def _extract(self, recordings: Sequence[Recording]) -> np.ndarray:
        raise NotImplementedError

    def _names(self) -> list[str]:
        raise NotImplementedError

    def _extractor_key(self) -> str:
        params = {k: v for k, v in self.get_params(deep=False).items() if k != "cache"}
        cls = type(self)
        return joblib.hash((CACHE_VERSION, cls.__module__, cls.__qualname__, self._version,
                            sorted((k, repr(v)) for k, v in params.items())))

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
            if stored.check_call_in_cache(ekey, k):
                out[i] = stored(ekey, k)
            else:
                missing.append(i)
        if missing:
            rows = self._checked(self._extract([recordings[i] for i in missing]),
                                 len(missing), n_out)
            for i, row in zip(missing, rows, strict=True):
                out[i] = stored(ekey, keys[i], row=row)
        return out

    @staticmethod
    def _checked(x: np.ndarray, n_rows: int, n_out: int) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (n_rows, n_out):
            raise RuntimeError(f"feature extractor returned shape {x.shape}, "
                               f"expected ({n_rows}, {n_out})")
        return x

    def fit(self, X: Sequence[Recording], y=None) -> RecordingFeatures:
        """Nothing to learn; records ``n_features_in_`` (1: one recording per row)."""
        _as_list(X)
        self.n_features_in_ = 1
        self.n_features_out_ = len(self._names())
        return self

    def transform(self, X: Sequence[Recording]) -> np.ndarray:
        """Features of each recording, shape (n_recordings, n_features)."""
        check_is_fitted(self, "n_features_out_")
        return self._rows(X)

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        """Readable feature names with units."""
        return np.asarray(self._names(), dtype=object)


def _as_list(recordings) -> list[Recording]:
    recordings = list(recordings)
    bad = [type(r).__name__ for r in recordings if not isinstance(r, Recording)]
    if bad:
        raise TypeError(f"feature sets take a list of Recording objects, got {bad[0]}")
    return recordings
