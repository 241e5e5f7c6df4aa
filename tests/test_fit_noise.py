"""The long-run covariance of a whole fit's scores (its sandwich's middle) and the map that
carries emcee's draws to the sandwich."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from frictionfit.fit._noise import RHO_CAP, bartlett_lags, long_run_covariance


def test_the_window_sums_are_the_bartlett_weighted_autocovariances():
    rng = np.random.default_rng(0)
    scores = rng.standard_normal((2, 300, 3))
    mask = np.ones((2, 300), bool)
    mask[1, 50:60] = False
    rho = np.array([0.5, 0.9])
    lags = bartlett_lags(rho, mask.sum(axis=1))
    out = long_run_covariance(scores, mask, rho)
    for i in range(2):
        x = np.where(mask[i][:, None], scores[i], 0.0)
        ref = x.T @ x
        for lag in range(1, lags[i] + 1):
            g = x[lag:].T @ x[:-lag]
            ref += (1 - lag / (lags[i] + 1)) * (g + g.T)
        np.testing.assert_allclose(out[i], ref, rtol=1e-10, atol=1e-10)
        assert np.all(np.linalg.eigvalsh(out[i]) > 0)


@pytest.mark.parametrize("rho", [0.0, 0.6, 0.9])
def test_it_recovers_the_long_run_variance_of_ar1_scores(rho):
    """For AR(1) scores the sum's variance per sample is ``(1 + rho) / (1 - rho)``."""
    rng = np.random.default_rng(1)
    n, reps = 20_000, 8
    e = rng.standard_normal((reps, n)) * np.sqrt(1 - rho**2)
    x = lfilter([1.0], [1.0, -rho], e, axis=1)[..., None]
    out = long_run_covariance(x, np.ones((reps, n), bool), np.full(reps, rho))[:, 0, 0] / n
    truth = (1 + rho) / (1 - rho)
    assert abs(np.median(out) / truth - 1) < 0.12, (np.median(out), truth)


def test_the_bandwidth_grows_with_the_correlation_and_fits_the_series():
    lags = bartlett_lags(np.array([0.0, 0.3, 0.8, 0.99, 0.99]), np.array([1000] * 4 + [20]))
    assert lags[0] == 0 and lags[0] < lags[1] < lags[2] < lags[3] and lags[4] == 19
    assert lags[3] == bartlett_lags(RHO_CAP, 1000)  # capped like the long-run variance


def test_the_sandwich_map_carries_one_covariance_to_the_other():
    from frictionfit.uncertainty.measurement import _sandwich_map

    rng = np.random.default_rng(2)
    a, b = rng.standard_normal((2, 4, 4))
    density = a @ a.T
    density[:, 3] = density[3, :] = 0.0  # a parameter the density does not curve
    cov = b @ b.T
    cov[:, 3] = cov[3, :] = 0.0
    m = _sandwich_map(density, cov)
    np.testing.assert_allclose(m @ density @ m.T, cov, atol=1e-10)
    np.testing.assert_allclose(m[3], np.eye(4)[3], atol=1e-12)  # its draws kept as they are
