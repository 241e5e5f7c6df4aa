"""The base class of every feature set over a list of recordings, with a content cache.

A feature set turns each :class:`~frictionfit.recording.Recording` into one row of
named features. Subclasses write :meth:`RecordingFeatures._extract` (a batch of
recordings -> rows; batching lets expensive sets such as the physical fits run all
trials in one call) and :meth:`RecordingFeatures._names`; a set that measures each
motion and takes the median over a recording's motions writes
:meth:`RecordingFeatures._motion_rows` instead, and gains ``transform_draws``: rows
drawn from the sampling distribution of that median (a bootstrap over the motions),
so a recording whose motions disagree, or that has few usable ones, carries that
uncertainty to the classifier; a set whose values come with their own uncertainty
(e.g. a fit's standard errors) keeps it in columns of the cached row that are not
features (:meth:`RecordingFeatures._stored_names`) and spreads the draws by it
(:meth:`RecordingFeatures._spread`). The base class gives
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
from collections.abc import Sequence
from pathlib import Path

import joblib
import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_is_fitted
from tqdm.auto import tqdm

from frictionfit.errors import DatasetError
from frictionfit.recording import MOTOR_POSITIONS, Recording, kept_per_recording

__all__ = ["FeatureWarning", "RecordingFeatures", "cache_dir", "content_key", "median_over_motions"]

#: Bump when the meaning of cached rows changes for every feature set.
CACHE_VERSION = 1


def cache_dir() -> Path:
    """Where feature rows are cached: ``$FRICTIONFIT_CACHE`` or ``~/.cache/frictionfit``."""
    env = os.environ.get("FRICTIONFIT_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "frictionfit"


@kept_per_recording
def content_key(rec: Recording) -> str:
    """A hash of everything a feature may read from ``rec`` (not its name or path)."""
    parts = [rec.t, rec.samples, rec.sample_rate_hz,
             [(c.name, c.unit) for c in rec.channels],
             [(e.t, e.kind, e.target) for e in rec.events],
             sorted((str(k), repr(v)) for k, v in rec.metadata.items())]
    reads = rec.extra.get(MOTOR_POSITIONS)  # the fitted sets time movements from them
    if reads is not None:  # (a recording without reads keeps its key)
        parts.append(reads)
    overloads = rec.overload_runs()  # the fits leave these samples out
    if overloads:  # (a recording without them keeps its key)
        parts.append(sorted(overloads.items()))
    return joblib.hash(tuple(parts))


def median_over_motions(rows: list[np.ndarray]) -> np.ndarray:
    """Per-feature median over motions, ignoring NaN; NaN only where every motion is NaN."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices stay NaN, on purpose
        return np.nanmedian(np.asarray(rows, dtype=np.float64), axis=0)


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
    training_rows_ : ndarray of shape (n_training_recordings, n_features)
        The training rows (NaN where not computed); ``transform_draws`` draws values that
        cannot be computed from them.
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
        out = np.full((len(recordings), len(self._stored_names())), np.nan)
        for i, rows in enumerate(self._cached_motion_rows(list(recordings))):
            if rows is not None and len(rows):
                out[i] = median_over_motions(rows)
        return out

    def _motion_rows(self, recordings: Sequence[Recording]) -> list[np.ndarray | None]:
        """Per recording, its motions' rows ``(n_motions, n_features)`` (None: no motion)."""
        raise NotImplementedError

    def _names(self) -> list[str]:
        raise NotImplementedError

    def _stored_names(self) -> list[str]:
        """The columns ``_extract`` returns and the cache holds: the features (``_names``),
        and any a set keeps for :meth:`_spread` only."""
        return self._names()

    def _exposed(self) -> np.ndarray:
        """Where the features sit among the stored columns."""
        stored = {n: j for j, n in enumerate(self._stored_names())}
        return np.asarray([stored[n] for n in self._names()], dtype=int)

    def _spread(self, draws: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Draws of stored columns ``(n_draws, n, n_stored)`` spread by what a set knows of
        each value's uncertainty beyond the bootstrap over motions (none here)."""
        return draws

    #: Parameters that choose which stored columns are shown, not what is stored: not in the
    #: cache key, so each view shares the rows of the others.
    _view_params: tuple[str, ...] = ()

    def _extractor_key(self) -> str:
        params = {k: v for k, v in self.get_params(deep=False).items()
                  if k != "cache" and k not in self._view_params}
        cls = type(self)
        return joblib.hash((CACHE_VERSION, cls.__module__, cls.__qualname__, self._version,
                            sorted((k, repr(v)) for k, v in params.items()),
                            self._stored_names()))

    def _rows(self, recordings: Sequence[Recording]) -> np.ndarray:
        """Rows of features for ``recordings``: cached ones loaded, all missing ones extracted
        in one batch."""
        recordings = _as_list(recordings)
        n_out = len(self._stored_names())
        if not self.cache:
            return self._checked(self._extract(recordings), len(recordings),
                                 n_out)[:, self._exposed()]
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
        blocks = self._blocks(recordings, missing)
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
        return out[:, self._exposed()]

    def _blocks(self, recordings: Sequence[Recording], missing: list[int]) -> list[list[int]]:
        """The batched extractions of the ``missing`` recordings: runs of :attr:`_block`."""
        size = self._block or max(len(missing), 1)
        return [missing[i:i + size] for i in range(0, len(missing), size)]

    @staticmethod
    def _checked(x: np.ndarray, n_rows: int, n_out: int) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (n_rows, n_out):
            raise RuntimeError(f"feature extractor returned shape {x.shape}, "
                               f"expected ({n_rows}, {n_out})")
        return x

    def fit(self, X: Sequence[Recording], y=None) -> RecordingFeatures:
        """Learn the fill value of each feature: its median over ``X`` (0 where all are NaN).

        A training recording none of whose features can be computed raises
        :class:`~frictionfit.errors.DatasetError` naming it: a row of fills would teach
        the classifier the training medians as that recording's class.
        """
        self._fit_rows(self._rows(X), X)
        return self

    def fit_transform(self, X: Sequence[Recording], y=None, **fit_params) -> np.ndarray:
        rows = self._rows(X)
        self._fit_rows(rows, X)
        return self._filled(rows, X)

    def _fit_rows(self, rows: np.ndarray, X: Sequence[Recording]) -> None:
        empty = [r.name for r, row in zip(_as_list(X), rows, strict=True)
                 if row.size and not np.isfinite(row).any()]
        if empty:
            raise DatasetError(
                f"{type(self).__name__}: no feature of {len(empty)} training recording(s) "
                f"could be computed ({', '.join(empty[:3])}{', ...' if len(empty) > 3 else ''}"
                "); see the warnings above for why, and leave them out of training")
        self.n_features_in_ = 1
        self.n_features_out_ = rows.shape[1]
        finite = np.isfinite(rows)
        counts = finite.sum(axis=0)
        medians = np.zeros(rows.shape[1])
        for j in np.flatnonzero(counts):
            medians[j] = np.median(rows[finite[:, j], j])
        self.fill_values_ = medians
        self.training_rows_ = rows

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

    def transform_draws(self, X: Sequence[Recording], n_draws: int,
                        rng: np.random.Generator) -> np.ndarray:
        """Rows drawn from each recording's sampling distribution, ``(n_draws, n, n_features)``.

        For a set built from motions: the median over a bootstrap resample of the
        recording's motions, one resample per draw, spread further by :meth:`_spread`
        (e.g. a fit's posterior); a value no resampled motion gives is drawn from that
        feature's training values. Other sets have no such distribution: every draw is
        the row of :meth:`transform`.
        """
        check_is_fitted(self, "fill_values_")
        X = _as_list(X)
        if type(self)._motion_rows is RecordingFeatures._motion_rows:
            rows = self.transform(X)
            return np.broadcast_to(rows, (n_draws, *rows.shape))
        out = np.full((n_draws, len(X), len(self._stored_names())), np.nan)
        for i, rows in enumerate(self._cached_motion_rows(X)):
            if rows is not None and len(rows):
                pick = rng.integers(0, len(rows), size=(n_draws, len(rows)))
                out[:, i] = median_over_motions(np.moveaxis(rows[pick], 1, 0))
        return self._drawn_where_missing(self._spread(out, rng)[..., self._exposed()], rng)

    def _drawn_where_missing(self, draws: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Missing values (NaN) drawn from that feature's training values: what the
        recording does not show may be anything seen in training (the training median
        where no training value exists)."""
        draws = draws.copy()
        for j in range(draws.shape[-1]):
            bad = ~np.isfinite(draws[..., j])
            if not bad.any():
                continue
            seen = self.training_rows_[:, j][np.isfinite(self.training_rows_[:, j])]
            draws[..., j][bad] = (rng.choice(seen, size=int(bad.sum())) if seen.size
                                  else self.fill_values_[j])
        return draws

    def _cached_motion_rows(self, recordings: list[Recording]) -> list[np.ndarray | None]:
        """:meth:`_motion_rows`, cached by recording content like the rows."""
        if not self.cache:
            return self._motion_rows(recordings)
        memory = joblib.Memory(cache_dir() / "features", verbose=0)
        stored = memory.cache(_stored_row, ignore=["row"])
        ekey = self._extractor_key() + ":motions"
        keys = [content_key(r) for r in recordings]
        found = {i: stored(ekey, k) for i, k in enumerate(keys)
                 if stored.check_call_in_cache(ekey, k)}
        missing = [i for i in range(len(recordings)) if i not in found]
        if missing:
            for i, rows in zip(missing, self._motion_rows([recordings[i] for i in missing]),
                               strict=True):
                found[i] = stored(ekey, keys[i], row=rows)
        return [found[i] for i in range(len(recordings))]


class FeatureWarning(UserWarning):
    """Some feature values could not be computed and were filled (see the message)."""


def _as_list(recordings) -> list[Recording]:
    recordings = list(recordings)
    bad = [type(r).__name__ for r in recordings if not isinstance(r, Recording)]
    if bad:
        raise TypeError(f"feature sets take a list of Recording objects, got {bad[0]}")
    return recordings
