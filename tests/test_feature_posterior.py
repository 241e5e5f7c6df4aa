"""Draws of the fitted features spread by each recording's fit posterior (small simulated set)."""

from __future__ import annotations

import numpy as np
import pytest

from frictionfit.features.physical import FittedFeatures
from frictionfit.recording import Recording
from frictionfit.simulation.measurements import simulate_measurements


def _noisier(rec: Recording, sd_n: float, seed: int) -> Recording:
    """``rec`` with white noise of ``sd_n`` (N) added to every channel."""
    noise = np.random.default_rng(seed).normal(0.0, sd_n, rec.samples.shape)
    return Recording.from_arrays(rec.samples + noise, rec.sample_rate_hz, rec.channel_names,
                                 events=rec.events, name=f"{rec.name}_noisy",
                                 metadata=rec.metadata)


@pytest.fixture(scope="module")
def fitted(feature_cache):
    """A clean simulated recording and its noisier twin, with the fitted features fitted
    on them and three other materials (one batch, the motor's timing per recording); the
    stderrs exposed."""
    clean, *others = simulate_measurements([(1, "paper-2", 1), (1, "carpet-1", 1),
                                            (1, "cushion-1", 1), (1, "scarf-2", 1)], seed=5)
    recs = [clean, _noisier(clean, 0.05, seed=1)]
    feats = FittedFeatures(rig="recording", with_stderr=True, relaxation=True).fit(recs + others)
    return feats, recs


def _columns(feats: FittedFeatures) -> tuple[np.ndarray, np.ndarray]:
    names = list(feats.get_feature_names_out())
    errors = np.flatnonzero(["_stderr [" in n for n in names])
    return errors - 1, errors  # each value sits just before its stderr


def test_fitted_draws_are_normal_about_the_value_with_the_fits_stderr(fitted):
    feats, recs = fitted
    values, errors = _columns(feats)
    rows = feats.transform(recs)
    draws = feats.transform_draws(recs, 2000, np.random.default_rng(0))
    se = rows[:, errors]
    spread = np.nanstd(feats.training_rows_[:, values], axis=0)
    ok = np.isfinite(se) & (se > 0) & (se <= spread)
    assert ok.sum() >= 10
    np.testing.assert_allclose(draws[:, :, values].std(axis=0)[ok], se[ok], rtol=0.1)
    centred = np.abs(draws[:, :, values].mean(axis=0) - rows[:, values]) <= 4 * se / np.sqrt(2000)
    assert centred[ok].all()
    kept = draws[:, :, errors]
    np.testing.assert_array_equal(kept, np.broadcast_to(se, kept.shape))


def test_a_value_less_certain_than_the_training_spread_is_drawn_from_training(fitted):
    """A stderr above the spread of that feature over the training recordings says the value
    tells recordings apart no better than chance: its draws are the training values."""
    feats, recs = fitted
    values, errors = _columns(feats)
    wide = np.zeros((len(recs), len(feats.get_feature_names_out())))
    wide[:, errors] = 1e6  # every fitted value far less certain than the training spread
    assert feats._stored_names() == feats._names()  # with_stderr: every stored column shown
    draws = feats._spread(np.broadcast_to(wide, (3, *wide.shape)), np.random.default_rng(0))
    assert np.isnan(draws[:, :, values]).all()  # left to _drawn_where_missing
    filled = feats._drawn_where_missing(draws, np.random.default_rng(0))
    for j in values:
        assert np.isin(filled[:, :, j], feats.training_rows_[:, j]).all()


def test_a_noisier_twin_has_wider_fitted_draws(fitted):
    feats, recs = fitted
    values, _ = _columns(feats)
    spread = feats.transform_draws(recs, 400, np.random.default_rng(0))[:, :, values].std(axis=0)
    assert np.median(spread[1] / spread[0]) > 1.5


def test_the_draws_are_seeded(fitted):
    feats, recs = fitted
    a = feats.transform_draws(recs, 8, np.random.default_rng(3))
    b = feats.transform_draws(recs, 8, np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, feats.transform_draws(recs, 8, np.random.default_rng(4)))


def test_the_stderr_is_cached_but_a_feature_only_on_request(fitted):
    feats, recs = fitted
    plain = FittedFeatures(rig="recording", relaxation=True).fit(recs)
    names = list(plain.get_feature_names_out())
    assert not any("_stderr" in n for n in names)
    assert len(feats.get_feature_names_out()) == 2 * len(names)
    values, _ = _columns(feats)
    # one cache for both views: the plain set reads the rows the fixture's fit stored
    np.testing.assert_array_equal(plain.transform(recs), feats.transform(recs)[:, values])
