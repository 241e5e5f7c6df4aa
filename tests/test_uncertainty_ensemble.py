"""The shared-ensemble emcee engine on a linear-Gaussian problem with a known posterior."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from frictionfit.uncertainty._ensemble import run_lockstep


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


@pytest.mark.parametrize("stage", ["pilot", "chain"])
def test_one_trials_failure_stays_with_that_trial(rng, monkeypatch, stage):
    from frictionfit.uncertainty import _ensemble

    evaluate, mean, cov = _linear_gaussian(rng, n_trials=3)
    real = _ensemble._Trial.refit if stage == "pilot" else _ensemble._Trial.restart

    def broken(self, *args):
        if self.index == 1:
            raise np.linalg.LinAlgError("degenerate draws")
        return real(self, *args)

    monkeypatch.setattr(_ensemble._Trial, "refit" if stage == "pilot" else "restart", broken)
    # A chain restarts only if tau > REFIT_MIN_TAU at a refit point: lower it so all do at 25
    monkeypatch.setattr(_ensemble, "REFIT_MIN_TAU", -1.0)
    chains = run_lockstep(evaluate, mean, cov, nwalkers=8, seed=0, max_steps=4000,
                          refit_at=(25,))
    assert isinstance(chains[1], np.linalg.LinAlgError)
    assert chains[0].converged and chains[2].converged


def test_one_call_per_step_holds_every_running_trial_until_it_stops(rng):
    calls = []
    evaluate, mean, cov = _linear_gaussian(rng, n_trials=4)

    def counting(U, idx):
        calls.append(np.bincount(idx, minlength=4))
        return evaluate(U, idx)

    chains = run_lockstep(counting, mean, cov, nwalkers=8, seed=0, max_steps=4000)
    calls = np.array(calls)
    assert set(np.unique(calls)) == {0, 8}  # a trial is in a call with all its walkers or not
    # every trial is evaluated in every call until its chain stops, then in none
    pilot = 3 * 30 + 1  # the initial state's call and the pilot steps
    for k, chain in enumerate(chains):
        n_calls = pilot + chain.n_steps + chain.n_pilot - 90
        assert np.all(calls[:n_calls, k] == 8) and np.all(calls[n_calls:, k] == 0)


def test_trials_in_a_batch_are_reproducible_from_the_seed(rng):
    evaluate, mean, cov = _linear_gaussian(rng, n_trials=2)
    a, b = (run_lockstep(evaluate, mean, cov, nwalkers=8, seed=4, max_steps=60)
            for _ in range(2))
    for ca, cb in zip(a, b, strict=True):
        np.testing.assert_array_equal(ca.samples, cb.samples)


def test_laplace_t_density_matches_scipy_and_its_draws(rng):
    from scipy import stats

    from frictionfit.uncertainty._proposal import Proposal, Proposals

    mean, cov = np.array([1.0, -2.0]), np.array([[2.0, 0.6], [0.6, 0.5]])
    prop = Proposals([Proposal.from_laplace(mean, cov, df=5.0)])
    x = rng.normal(size=(1, 7, 2))
    exact = stats.multivariate_t(mean, cov, df=5).logpdf(x[0])
    np.testing.assert_allclose(prop.logpdf(x)[0], exact, rtol=1e-10)
    draws = prop.rvs(20000, np.random.RandomState(0))[0]
    np.testing.assert_allclose(np.cov(draws.T), cov * 5 / 3, rtol=0.1)


def test_ridge_map_is_an_inverse_pair_and_straightens_a_banana(rng):
    from frictionfit.uncertainty._proposal import MultivariateT, Proposal, Proposals, RidgeMap

    s = rng.normal(size=4000)
    draws = np.stack([s, 0.8 * s**2 + 0.05 * rng.normal(size=s.size)], axis=1)
    ridge = RidgeMap.fit(draws)
    assert ridge.r == 0
    np.testing.assert_allclose(ridge.inverse(ridge.forward(draws)), draws, atol=1e-12)
    assert np.std(ridge.forward(draws)[:, 1]) < 0.1  # the curved ridge is now straight
    laplace = MultivariateT(draws.mean(0), np.cov(draws.T))
    prop = Proposals([Proposal.fit(draws, laplace)])
    x = prop.rvs(5, np.random.RandomState(1))
    assert x.shape == (1, 5, 2) and np.all(np.isfinite(prop.logpdf(x)))
    np.testing.assert_allclose(prop.inverse(prop.forward(x)), x, atol=1e-12)


def test_stacked_proposals_score_and_move_each_trial_as_its_own(rng):
    """Trials stacked into one Proposals give each trial the density it has alone."""
    from frictionfit.uncertainty._proposal import MultivariateT, Proposal, Proposals

    singles = []
    for k in range(3):
        s = rng.normal(size=2000)
        draws = np.stack([s + k, (0.5 + k) * s**2 + 0.1 * rng.normal(size=s.size),
                          rng.normal(size=s.size)], axis=1)
        laplace = MultivariateT(draws.mean(0), np.cov(draws.T))
        singles.append(Proposal.from_laplace(draws.mean(0), np.cov(draws.T)) if k == 0
                       else Proposal.fit(draws, laplace))
    stacked = Proposals(singles)
    x = stacked.rvs(6, np.random.RandomState(2))
    for k, single in enumerate(singles):
        np.testing.assert_allclose(stacked.logpdf(x)[k], Proposals([single]).logpdf(x[k:k + 1])[0],
                                   rtol=1e-12)
    new, factor = stacked.independence(x.reshape(-1, 3), np.random.RandomState(3))
    np.testing.assert_allclose(factor, (stacked.logpdf(x) - stacked.logpdf(
        new.reshape(x.shape))).ravel())


def test_sampling_coordinates_carry_the_same_posterior():
    """log p_x(x) = log p_u(u(x)) + log |du/dx| (the priors become flat boxes)."""
    from frictionfit.fit import Trials
    from frictionfit.models import get_model
    from frictionfit.uncertainty._logpost import (
        from_sampling,
        logp_rows,
        on_device,
        to_sampling,
    )

    model = get_model("elastic_plastic")
    t = np.arange(400) / 1000.0
    u = np.array([[0.1, 0.3, -0.2, 0.0, 0.4], [0.0, -1.0, 0.5, 0.3, -0.2]])
    y = np.zeros((2, t.size))
    data = (on_device(Trials.from_arrays(y, t, (0.05, 0.25), direction=np.ones(2))),
            np.ones(2), np.zeros(2))
    x = to_sampling(model, u)
    np.testing.assert_allclose(from_sampling(model, x), u, atol=1e-9)
    idx = np.arange(2)
    lp_u = np.asarray(logp_rows(model)(u, idx, *data))
    lp_x = np.asarray(logp_rows(model, True)(x, idx, *data))
    h = 1e-6
    dxdu = (to_sampling(model, u + h) - to_sampling(model, u - h)) / (2 * h)
    diff = lp_x - (lp_u - np.sum(np.log(dxdu), axis=1))
    np.testing.assert_allclose(diff, diff[0], atol=1e-6)  # equal up to one constant
    outside = x.copy()
    outside[0, 1] = 99.0  # log stiffness beyond its bound
    assert np.asarray(logp_rows(model, True)(outside, idx, *data))[0] == -np.inf


def test_integrated_time_is_emcees_estimator(rng):
    import emcee

    from frictionfit.uncertainty._ensemble import integrated_time

    for n, rho in ((37, 0.0), (300, 0.6), (1000, 0.95)):  # lengths below and above 2^k
        e = rng.standard_normal((n, 6, 3))
        x = np.zeros_like(e)
        for k in range(n):
            x[k] = rho * x[k - 1] + e[k] if k else e[k]
        np.testing.assert_allclose(integrated_time(x),
                                   emcee.autocorr.integrated_time(x, tol=0), rtol=1e-10)


def test_split_rhat_is_arviz_rank_rhat(rng):
    import warnings

    from frictionfit.uncertainty._ensemble import split_rhat

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # arviz announces its refactor
        import arviz as az
    x = rng.standard_normal((301, 12, 3))  # an odd length: the middle step is dropped
    x[:, 0, 1] += 2.0  # one walker elsewhere
    x[100:250, 5, 2] = x[100, 5, 2]  # one walker stuck: ties in the ranks
    ours = split_rhat(x)
    theirs = [az.rhat(x[..., j].T, method="rank") for j in range(3)]  # (chain, draw)
    np.testing.assert_allclose(ours, theirs, rtol=1e-12)
    assert ours[0] < 1.01 < ours[1]


def test_walkers_that_disagree_are_not_converged_though_tau_is_short(rng):
    from frictionfit.uncertainty._ensemble import RHAT_MAX, _extend, _Trial
    from frictionfit.uncertainty._proposal import Proposal

    def trial(offset):
        tr = _Trial(0, Proposal.from_laplace(np.zeros(2), np.eye(2)), [])
        result = None
        for _ in range(3):  # independent draws: tau ~ 1, stable, far below 50 tau
            block = rng.standard_normal((200, 10, 2))
            block[:, 0] += offset  # walker 0 sits elsewhere all along
            result = _extend(tr, block, np.zeros((200, 10)), np.full(10, 200.0),
                             max_steps=600, min_tau_multiple=50, tau_rtol=1.0,
                             min_acceptance=0.1)
            if result is not None:
                break
        return result

    agree, disagree = trial(0.0), trial(1.5)
    assert agree.converged and agree.n_steps == 400 and np.all(agree.rhat <= RHAT_MAX)
    assert disagree.tau.max() < 600 / 50  # the tau rule alone would pass it
    assert not disagree.converged and disagree.n_steps == 600 and disagree.rhat.max() > 1.05
