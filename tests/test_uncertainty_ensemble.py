"""The lockstep emcee engine on a linear-Gaussian problem with a known posterior."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from frictionfit.uncertainty._ensemble import _Lockstep, run_lockstep


def _linear_gaussian(rng, n_trials=3, n_obs=40, p=3, noise_sd=0.5, prior_sd=3.0):
    """y = A theta + e per trial, Gaussian prior: the exact posterior mean and covariance."""
    x = np.linspace(-1, 1, n_obs)
    A = np.stack([x**k for k in range(p)], axis=1)
    theta = rng.normal(0, 1, (n_trials, p))
    y = theta @ A.T + noise_sd * rng.standard_normal((n_trials, n_obs))
    prec = A.T @ A / noise_sd**2 + np.eye(p) / prior_sd**2
    cov = np.linalg.inv(prec)
    mean = (y @ A / noise_sd**2) @ cov
    cov = np.broadcast_to(cov, (n_trials, p, p)).copy()
    Aj, yj = jnp.asarray(A), jnp.asarray(y)

    @jax.jit
    def logp(U, idx):
        r = jnp.einsum("rj,nj->rn", U, Aj) - yj[idx]
        return -0.5 * jnp.sum(r**2, axis=1) / noise_sd**2 - 0.5 * jnp.sum(U**2, 1) / prior_sd**2

    return (lambda U, idx: np.asarray(logp(jnp.asarray(U), jnp.asarray(idx)))), mean, cov


def test_linear_gaussian_mean_and_sd_match_the_analytic_posterior(rng):
    evaluate, mean, cov = _linear_gaussian(rng)
    # Start from a deliberately wrong Laplace guess (shifted, inflated): the chain must
    # still find the exact posterior, not echo its starting Gaussian.
    start = mean + 0.5 * np.sqrt(np.einsum("tii->ti", cov))
    chains = run_lockstep(evaluate, start, 2.0 * cov, nwalkers=12, seed=1, max_steps=4000)
    for k, chain in enumerate(chains):
        assert chain.converged, chain
        assert chain.n_steps >= 50 * chain.tau.max()
        flat = chain.samples.reshape(-1, mean.shape[1])
        sd = np.sqrt(np.diag(cov[k]))
        ess = chain.ess()
        # Monte-Carlo error of a mean is sd / sqrt(ESS); of an sd about sd / sqrt(2 ESS).
        # 4.5 sigma over 3 trials x 3 parameters x 2 checks keeps false alarms < 1e-3.
        np.testing.assert_array_less(np.abs(flat.mean(0) - mean[k]), 4.5 * sd / np.sqrt(ess))
        np.testing.assert_array_less(np.abs(flat.std(0) - sd), 4.5 * sd / np.sqrt(2 * ess))


def test_a_step_cap_below_50_tau_is_flagged_not_converged(rng):
    evaluate, mean, cov = _linear_gaussian(rng, n_trials=2)
    chains = run_lockstep(evaluate, mean, cov, nwalkers=8, seed=0, max_steps=20,
                          check_every=10)
    assert [c.converged for c in chains] == [False, False]
    assert all(c.n_steps == 20 for c in chains)


def test_an_evaluation_error_reaches_every_trial_without_hanging(rng):
    def broken(U, idx):
        raise RuntimeError("model blew up")

    chains = run_lockstep(broken, np.zeros((3, 2)), np.stack([np.eye(2)] * 3), nwalkers=6)
    assert all(isinstance(c, RuntimeError) and "blew up" in str(c) for c in chains)


def test_lockstep_batches_all_running_trials_into_one_call(rng):
    calls = []
    evaluate, mean, cov = _linear_gaussian(rng, n_trials=4)

    def counting(U, idx):
        calls.append(np.unique(idx).size)
        return evaluate(U, idx)

    run_lockstep(counting, mean, cov, nwalkers=8, seed=0, max_steps=50, check_every=50)
    # Moves need one (independence) or two (DE, half ensembles) calls per step, so
    # trials finish after different numbers of calls; until then, calls hold all four.
    assert max(calls) == 4 and np.median(calls) == 4


def test_a_single_trial_is_evaluated_at_once():
    box = _Lockstep(lambda batch: {s: x.sum(axis=1) for s, x in batch.items()}, 1)
    assert box.log_prob(0)(np.ones((2, 3))).tolist() == [3.0, 3.0]
