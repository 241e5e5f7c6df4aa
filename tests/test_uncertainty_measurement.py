"""Posteriors of whole fits on simulated measurements: one likelihood behind the fit's
covariance, its BIC, Laplace and emcee; emcee against Laplace; seeds, failed rows."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from frictionfit.errors import FitError, Status
from frictionfit.fit._noise import RHO_CAP, ar1_log_likelihood
from frictionfit.fit._whole_problem import stack_items
from frictionfit.fit.result import take_trials
from frictionfit.simulation.materials import CLASSES
from frictionfit.simulation.measurements import simulate_measurements
from frictionfit.uncertainty import (
    corner_plot,
    measurement_posterior,
    posterior_summary,
    to_arviz,
    whole_fit_posterior,
)
from frictionfit.whole_fit import fit_recordings

#: Well identified in both recordings: unflagged, stderr a few per cent of the value.
IDENTIFIED = ("k", "f_kin")


@pytest.fixture(scope="module")
def fitted():
    """Two simulated measurements (index_x) and their whole fits with the law without a
    static peak (emcee mixes slowly where a relaxation branch sits at its bound, as the
    larger law's second branch does on these); the first has no flagged parameter (its
    posterior is near-Gaussian)."""
    recs = simulate_measurements([(1, CLASSES[0], 1), (2, CLASSES[1], 1)], seed=0)
    res = fit_recordings(recs, channels=["index_x"], model="no_peak2", progress=False)
    assert (res.status == Status.CONVERGED).all()
    assert not any(n in res.flags[0] for n in IDENTIFIED)
    return res.items, res


@pytest.fixture(scope="module")
def laplace(fitted):
    _, res = fitted
    return res.posterior(method="laplace", seed=1)


def test_the_bic_is_the_likelihood_at_the_noise_the_posteriors_take(fitted):
    """The law choice's BIC is ``-2 log L + (p + 1) log n`` of the one AR(1) likelihood at
    the noise the fit keeps (``noise_sd``, ``noise_rho``: its maximum), the constant
    ``n (1 + log 2 pi)`` dropped; the posteriors' variance per block is that noise's
    long-run variance."""
    _, res = fitted
    for i in range(res.n_trials):
        d = res.items[i]
        log_l = ar1_log_likelihood(res.residuals(i)[None], d.mask[None],
                                   res.noise_sd[i:i + 1], res.noise_rho[i:i + 1])[0]
        n, p = int(d.mask.sum()), int(res.nvarys[i])
        bic = -2 * log_l - n * (1 + np.log(2 * np.pi)) + (p + 1) * np.log(n)
        # the residuals recomputed by the value-only loop, the fit's by the vmapped one
        assert res.bic[i] == pytest.approx(bic, rel=1e-9, abs=1e-6)
        rho = res.noise_rho[i]
        r = min(rho, RHO_CAP)
        assert res.noise_var[i] == pytest.approx(res.noise_sd[i] ** 2 * (1 + r) / (1 - r))


def test_laplace_draws_follow_the_fits_covariance(fitted, laplace):
    _, res = fitted
    assert laplace.method == ["laplace", "laplace"] and laplace.converged.all()
    for i in range(2):
        for name in IDENTIFIED:
            q = laplace.quantiles[i][name]
            assert q[0] < q[1] < res.values[name][i] < q[3] < q[4]


def test_laplace_is_the_default(fitted, laplace):
    _, res = fitted
    default = res.posterior(seed=1)
    assert default.method == ["laplace", "laplace"]
    np.testing.assert_array_equal(default.quantiles[0]["k"], laplace.quantiles[0]["k"])


def test_laplace_is_deterministic_given_the_seed(fitted, laplace):
    _, res = fitted
    again = res.posterior(method="laplace", seed=1)
    other = whole_fit_posterior(res, method="laplace", seed=2)
    for name in IDENTIFIED:
        np.testing.assert_array_equal(again.quantiles[0][name], laplace.quantiles[0][name])
        assert not np.array_equal(other.quantiles[0][name], laplace.quantiles[0][name])


def test_emcee_agrees_with_laplace_on_a_well_identified_recording(fitted, laplace, tmp_path):
    _, res = fitted
    mc = take_trials(res, [0]).posterior(method="emcee", seed=0, max_steps=2000)
    assert mc.method == ["emcee"] and mc.converged[0], mc.reason
    for name in IDENTIFIED:
        sd = laplace.sd[0][name]
        # emcee's density adds the bounds' log-uniform prior and is not exactly Gaussian
        # (k is skewed to the right): medians within 0.5 sd, sds within a factor 1.5
        assert abs(mc.quantiles[0][name][2] - laplace.quantiles[0][name][2]) < 0.5 * sd
        ratio = mc.sd[0][name] / sd
        assert ratio > 1 / 1.5 and ratio < 1.5
    table = posterior_summary(mc)
    assert set(IDENTIFIED) <= set(table["param"]) and table["converged"].all()
    draws = to_arviz(mc, 0).posterior["k"].to_numpy()
    assert np.median(draws) == pytest.approx(mc.quantiles[0]["k"][2], rel=1e-6)
    mc.chains[0].samples[..., -1] = 0.0  # as a parameter held at the fit: left out
    corner_plot(mc, 0, tmp_path / "corner.png")
    assert (tmp_path / "corner.png").stat().st_size > 0


def test_emcee_is_deterministic_given_the_seed(fitted):
    _, res = fitted
    kw = dict(method="emcee", seed=3, max_steps=20, pilot_steps=10, check_every=10)
    a, b = (take_trials(res, [0]).posterior(**kw) for _ in range(2))
    assert not a.converged[0] and "NOT CONVERGED after 20 steps" in a.reason[0]
    np.testing.assert_array_equal(a.chains[0].samples, b.chains[0].samples)


def test_a_failed_row_gets_a_status_not_silent_nan(fitted):
    _, res = fitted
    broken = dataclasses.replace(res, status=res.status.copy(), cov=list(res.cov))
    broken.status[0] = Status.NONFINITE
    broken.cov[1] = np.full_like(res.cov[1], np.nan)
    for method in ("laplace", "auto"):
        post = broken.posterior(method=method)
        assert post.method == ["none", "none"] and not post.converged.any()
        assert post.reason[0] == "skipped: fit status nonfinite"
        assert post.reason[1].startswith("skipped: covariance not finite")
        assert np.isnan(post.sd[0]["k"]) and not posterior_summary(post)["converged"].any()


def test_only_whole_fits_are_accepted(fitted):
    from frictionfit.fit import FitResult

    items, res = fitted
    stroke = FitResult(**{f.name: getattr(res, f.name)
                          for f in dataclasses.fields(FitResult) if f.init})
    with pytest.raises(FitError, match="needs a whole fit"):
        whole_fit_posterior(stroke)
    from frictionfit.uncertainty import sample_posterior

    with pytest.raises(FitError, match="a whole fit samples its own"):
        sample_posterior(res, np.zeros((2, 10)), np.arange(10.0), (0.1, 0.5))
    with pytest.warns(DeprecationWarning, match="measurement_posterior is deprecated"), \
            pytest.raises(FitError, match="1 items but the fit has 2 rows"):
        measurement_posterior(res, items[:1])


def test_emcee_starts_inside_a_bound_with_width_along_it(fitted):
    """emcee samples in the fit's unconstrained ``u``, where the density (flat on the value's
    bounds, times the logistic Jacobian) has its mode inside every bound: started with a
    parameter put on its bound (``u`` = 40, where the logistic map's slope is 0), the search
    for emcee's first proposal goes back to the mode, with a finite, non-zero width."""

    from frictionfit.uncertainty.measurement import _U_START, _density, _proposal_start

    items, res = fitted
    model = res.member(0)
    free = tuple(model.param_names.index(p) for p in res.free_names(0))
    u = np.stack(res.u)
    j = free.index(model.param_names.index("relax_frac2"))
    u_free = u[:, list(free)].copy()
    u_free[:, j] = 40.0
    data = stack_items(items, u)
    mode, covs = _proposal_start(model, free, u_free, data, res.noise_var)
    density = _density(model, free, data, res.noise_var)
    start = np.clip(u_free, -_U_START, _U_START)
    for k in range(2):
        sd = np.sqrt(np.diag(covs[k]))
        assert np.all(np.isfinite(sd)) and np.all(sd > 0)
        if abs(u[k, free[j]]) < _U_START:  # the fit's optimum inside: back there
            assert abs(mode[k, j] - u[k, free[j]]) < 2 * sd[j]
        # a maximum along relax_frac2: higher than a width either side and than the start
        points = np.repeat(mode[k][None], 4, axis=0)
        points[1:, j] += (-sd[j], sd[j], 0.0)
        points[3] = start[k]
        lp = density(points, np.full(4, k))
        assert np.all(lp[0] >= lp[1:])


def test_the_density_emcee_samples_has_the_fits_density_covariance_at_its_mode(fitted):
    """emcee's density is the fit's own: at the fit's optimum its gradient vanishes and its
    Gauss-Newton curvature (the data's and the priors' rows over the noise's long-run
    variance) is the inverse of the fit's ``density_cov``, which the sandwich map carries to
    the fit's covariance; the host's density (the value-only loop) is the Gauss-Newton
    path's (the loop with its Jacobian) around it."""
    import jax.numpy as jnp

    from frictionfit.fit._stats import VANISHING
    from frictionfit.uncertainty.measurement import _bounded, _density, _gauss_newton_fn

    items, res = fitted
    model = res.member(0)
    free = tuple(model.param_names.index(p) for p in res.free_names(0))
    u = np.stack(res.u)
    data = stack_items(items, u)
    curvature = _gauss_newton_fn(model, free)
    density = _density(model, free, data, res.noise_var)
    rng = np.random.default_rng(0)
    for i in range(2):
        row, s2 = data.take(i), res.noise_var[i]
        points = u[i, list(free)] + np.vstack([np.zeros(len(free)),
                                               0.05 * rng.standard_normal((3, len(free)))])
        host = density(points, np.full(4, i))
        for point, lp in zip(points, host, strict=True):
            ref = curvature(jnp.asarray(point), row, s2, _bounded(model, free))[0]
            np.testing.assert_allclose(lp, float(ref), rtol=1e-9)
        _, grad, hess = (np.asarray(a) for a in curvature(
            jnp.asarray(u[i, list(free)]), row, s2, jnp.zeros(len(free), bool)))
        # a parameter on its bound has a vanishing column: compare the others
        inside = [j for j, n in enumerate(res.free_names(i))
                  if res.flags[i].get(n) not in VANISHING]
        cov = np.linalg.inv(hess[np.ix_(inside, inside)])
        sd = np.sqrt(np.diag(res.density_cov[i]))[inside]
        # the solver's J^T J (in the vmapped pool) against one outside it: ~1e-3
        np.testing.assert_allclose(np.sqrt(np.diag(cov)), sd, rtol=5e-3)
        # the optimum is the density's mode: its gradient is < 0.01 of a unit step's
        # change of the log density in sd units (the solver's tolerances)
        assert np.all(np.abs(grad[inside] * sd) < 1e-2), grad[inside] * sd


@pytest.mark.slow
def test_emcee_agrees_with_laplace_on_the_law_with_a_static_peak():
    """On ``relaxation2`` (a static peak and two relaxation branches: the law ``"auto"``
    starts from), not only on the peak-less one, for a recording whose fit flags nothing:
    emcee converges, and its medians of the law's five key parameters lie within 0.5
    Laplace sd of Laplace's, its sds within a factor 1.5 (the density adds the bounds'
    priors and is not exactly Gaussian). Where a branch is gated (its fraction not told
    from 0) the chain mixes too slowly to converge in a test's budget."""
    rec, = simulate_measurements([(1, CLASSES[0], 1)], seed=0)
    res = fit_recordings(rec, channels=["index_x"], model="relaxation2", progress=False)
    assert res.flags[0] == {}, res.flags[0]
    lap = res.posterior(method="laplace", seed=1)
    mc = res.posterior(method="emcee", seed=0, max_steps=4000)
    assert mc.method == ["emcee"] and mc.converged[0], mc.reason
    for name in ("k", "f_kin", "f_static_excess", "relax_frac", "tau"):
        sd = lap.sd[0][name]
        assert abs(mc.quantiles[0][name][2] - lap.quantiles[0][name][2]) < 0.5 * sd, name
        assert sd / 1.5 < mc.sd[0][name] < 1.5 * sd, name


def test_held_spread_adds_the_held_covariance_to_the_draws():
    from frictionfit.uncertainty._ensemble import ChainResult
    from frictionfit.uncertainty.measurement import _with_held_spread

    samples = np.zeros((400, 50, 3))
    chain = ChainResult(samples, np.ones(3), 400, 0, 1, 0.5, True)
    held = np.array([[0.04, 0.01], [0.01, 0.09]])
    spread = _with_held_spread(chain, [0, 2], held, np.random.default_rng(0))
    flat = spread.samples.reshape(-1, 3)
    np.testing.assert_allclose(np.cov(flat[:, [0, 2]].T), held, rtol=0.05, atol=1e-3)
    assert np.all(flat[:, 1] == 0.0) and np.all(chain.samples == 0.0)  # the chain is kept
    assert _with_held_spread(chain, [0, 2], np.zeros((2, 2)), None) is chain


@pytest.fixture(scope="module")
def session_held():
    """Two simulated recordings of one session, fitted with the motor's profile and the
    finger's creep held at the session's (their uncertainty in ``held_cov``)."""
    recs = simulate_measurements([(1, CLASSES[0], 1), (1, CLASSES[0], 2)], seed=0)
    res = fit_recordings(recs, channels=["index_x"], model="no_peak2", rig="session",
                         creep="session", progress=False)
    assert (res.status == Status.CONVERGED).all()
    return res


def test_a_session_held_fit_records_what_its_holds_add(session_held):
    res = session_held
    for i in range(res.n_trials):
        assert not {"ramp", "accel", "tau2"} & set(res.free_names(i))
        held = res.held_cov[i]
        assert held.shape == res.cov[i].shape and np.any(held)
        assert np.all(np.linalg.eigvalsh(held) > -1e-12)  # a covariance
        assert np.all(np.linalg.eigvalsh(res.cov[i] - held) > -1e-12)  # cov at held values


def test_emcee_of_a_session_held_fit_converges_and_carries_the_held_spread(session_held,
                                                                           monkeypatch):
    import frictionfit.uncertainty.measurement as um

    start = um._proposal_start
    started = {}

    def too_wide(*args):  # twice the density's spread: only the density brings it back
        centre, covs = start(*args)
        started["covs"] = 4.0 * covs
        return centre, started["covs"]

    monkeypatch.setattr(um, "_proposal_start", too_wide)
    res = take_trials(session_held, [0])
    laplace = res.posterior(method="laplace", seed=0)
    mc = res.posterior(method="emcee", seed=0, max_steps=2000)
    assert mc.converged[0], mc.reason
    names = res.free_names(0)
    assert "tau2" not in names and np.isnan(mc.rhat[0]["tau2"])  # held: not sampled
    free_l = [res.member(0).param_names.index(n) for n in names]
    centre = np.asarray(res.u[0])[free_l]
    carry = um._sandwich_map(res.density_cov[0], res.cov[0] - res.held_cov[0])
    carried = mc.chains[0].samples[..., free_l].reshape(-1, len(free_l))
    sampled = centre + np.linalg.solve(carry, (carried - centre).T).T
    for name in IDENTIFIED:
        # the chain itself samples at the held values: its spread is Laplace's there (the
        # fit's covariance less what the holds add), not the widened one
        j, jj = res.member(0).param_names.index(name), names.index(name)
        at_held = np.sqrt(res.cov[0][jj, jj] - res.held_cov[0][jj, jj])
        widened = np.sqrt(res.cov[0][jj, jj])
        chain_sd = np.std(mc.chains[0].samples[..., j])  # unconstrained coordinates
        assert abs(chain_sd / at_held - 1) < abs(chain_sd / widened - 1), (name, chain_sd)
        # before its affine carry onto the fit's covariance, the chain sampled the density,
        # whose spread is its own Gauss-Newton covariance's (``density_cov``), not the
        # proposal's it started from (twice that)
        sampled_sd = np.std(sampled[..., jj])
        density_sd = np.sqrt(res.density_cov[0][jj, jj])
        start_sd = np.sqrt(started["covs"][0][jj, jj])
        assert start_sd / density_sd > 1.5, (name, start_sd / density_sd)  # outside the band
        assert 1 / 1.08 < sampled_sd / density_sd < 1.08, (name, sampled_sd / density_sd)
        # reported: both with the holds' spread (a chain of the proposal: 2x)
        ratio = mc.sd[0][name] / laplace.sd[0][name]
        assert 1 / 1.08 < ratio < 1.08, (name, ratio)
    # the held values' variance added to the chain's (the sensor's: identity coordinates)
    for name in ("offset", "drift", "leak"):
        j, jj = res.member(0).param_names.index(name), names.index(name)
        chain_var = np.var(mc.chains[0].samples[..., j])
        np.testing.assert_allclose(mc.sd[0][name] ** 2, chain_var + res.held_cov[0][jj, jj],
                                   rtol=0.03)
