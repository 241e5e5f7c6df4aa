"""Batched fits: known truth, statuses, masking, determinism, auto selection output."""

import numpy as np
import pytest

from frictionfit.errors import FitError, Status
from frictionfit.fit import fit_report, fit_trials
from frictionfit.simulation.trials import simulate_trials


@pytest.fixture(scope="module")
def stick_slip_fit():
    ts = simulate_trials("stick_slip", 8, seed=11, snr_db=30.0)
    return ts, fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model="stick_slip", chunk_size=8)


def test_recovers_friction_levels(stick_slip_fit):
    ts, res = stick_slip_fit
    # Friction levels are the well-identified quantities at 30 dB; 5% median is the
    # issue's bar.
    for name in ("f_kin", "offset"):
        est = res.values[name].to_numpy()
        rel = np.abs(est - ts.truth[name]) / np.maximum(np.abs(ts.truth[name]), 0.05)
        assert np.median(rel) < 0.05, (name, rel)
    assert np.isfinite(res.values.to_numpy()).all()


def test_recovers_stiffness_within_its_stated_uncertainty(stick_slip_fit):
    ts, res = stick_slip_fit
    # On a single stroke k trades off with the movement duration (the contact sticks on
    # the drive's quadratic start): every trial is flagged so, and its error is tens of
    # per cent on some. What the fit states must still hold: the truth within 3 stderr on
    # every trial (the stderr an interval despite the flag), and a median error below
    # 0.2 (the trade-off's scale at 30 dB: about twice the median on these 8).
    k, se, truth = res.values["k"].to_numpy(), res.stderr["k"].to_numpy(), ts.truth["k"]
    assert np.all(np.isfinite(se) & (se > 0))
    assert np.all(np.abs(k - truth) < 3 * se), (k - truth) / se
    assert np.median(np.abs(k / truth - 1)) < 0.2, k / truth


def test_nan_samples_are_masked_not_propagated():
    ts = simulate_trials("elastic_plastic", 4, seed=2)
    y = ts.y.copy()
    y[0, 300:900] = np.nan  # 30% missing
    y[1, :] = np.nan  # nothing left
    res = fit_trials(y, ts.t, (ts.t_out, ts.t_back), model="elastic_plastic", chunk_size=4)
    assert Status(int(res.status[1])) is Status.INSUFFICIENT_DATA
    assert np.isfinite(res.chi2[0]) and res.status[0] != Status.NONFINITE
    # lmfit's counts: the masked samples are not data points
    assert res.ndata[0] == np.isfinite(y[0]).sum() < res.ndata[2] == y.shape[1]
    assert res.nvarys[0] == len(res.free_names(0))
    assert f"# data points      = {res.ndata[0]}" in fit_report(res, 0)
    frame = res.to_frame()
    assert frame["ndata"].tolist() == res.ndata.tolist()
    assert len(frame) == 4
    # nothing was fitted to the empty trial: its numbers are NaN, not the starting point;
    # its parameters are still its model's
    assert list(res.params(1)) == list(res.member(1).param_names)
    assert np.isnan(list(res.params(1).values())).all()
    assert frame.filter(regex=r"^(k|f_kin|offset)(_stderr)? \[").iloc[1].isna().all()
    assert frame.filter(regex=r"^(k|f_kin|offset) \[").iloc[0].notna().all()


def test_same_input_gives_bit_identical_results():
    ts = simulate_trials("elastic_plastic", 3, seed=5)
    a = fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model="elastic_plastic", chunk_size=4)
    b = fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model="elastic_plastic", chunk_size=4)
    assert np.array_equal(np.stack(a.u), np.stack(b.u))


def test_report_and_frame_name_units_and_flags(stick_slip_fit):
    _, res = stick_slip_fit
    text = fit_report(res, 0)
    assert "[[Variables]]" in text and "N/mm" in text and "Bayesian info crit" in text
    frame = res.to_frame()
    assert {"f_kin [N]", "f_kin_stderr [N]", "status", "bic"} <= set(frame.columns)


def test_report_shows_starting_values_and_strong_correlations(stick_slip_fit):
    _, res = stick_slip_fit
    report = fit_report(res, 0)
    assert f"(init = {res.init[0]['k']:.6g})" in report
    pairs = {k: r for k, r in res.correl[0].items() if abs(r) >= 0.1}
    assert "[[Correlations]]" in report and len(pairs) >= 1
    (a, b), r = max(pairs.items(), key=lambda kv: abs(kv[1]))
    assert f"C({a}, {b}) = {r:+.4f}" in report
    assert all(-1.0 <= r <= 1.0 for r in res.correl[0].values())
    assert repr(res).startswith(f"FitResult({res.n_trials} trials, models")


def test_values_by_column_and_results_of_two_laws_concatenated(stick_slip_fit):
    from frictionfit.fit.result import concat_results, take_trials

    _, slip = stick_slip_fit
    ts = simulate_trials("elastic_plastic", 2, seed=2)
    plastic = fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model="elastic_plastic",
                         chunk_size=4)
    for res in (slip, plastic):
        assert list(res.values.columns) == list(res.member(0).param_names)
        assert (res.values.dtypes == np.float64).all()
        assert list(res.stderr.index) == list(range(res.n_trials))
        for i in range(res.n_trials):
            assert res.values["k"][i] == res.params(i)["k"]
            assert res.stderr["k"][i] == res.stderrs(i)["k"]
    merged = concat_results([plastic, slip])
    own = [plastic.params(i) for i in range(2)] + [slip.params(i) for i in range(8)]
    assert list(own[0]) == ["offset", "k", "f_kin", "delay", "ramp"]
    # the union of the laws' parameters, in the order they first appear
    assert list(merged.values.columns) == [*own[0], "f_static_excess", "slip_length"]
    assert list(merged.stderr.columns) == list(merged.values.columns)
    assert merged.values["slip_length"][:2].isna().all()
    assert merged.values["slip_length"][2:].notna().all()
    np.testing.assert_equal([merged.params(i) for i in range(10)], own)
    assert [list(merged.params(i)) for i in range(10)] == [list(o) for o in own]
    np.testing.assert_equal(merged.stderrs(9), slip.stderrs(7))
    assert "slip_length [mm]" not in plastic.to_frame()
    assert merged.to_frame()["slip_length [mm]"][:2].isna().all()
    back = take_trials(merged, [3, 0])
    assert back.model == ["stick_slip", "elastic_plastic"] and back.n_trials == 2
    assert list(back.values.index) == [0, 1]
    np.testing.assert_equal([back.params(0), back.params(1)], [own[3], own[0]])
    np.testing.assert_equal(back.stderrs(1), plastic.stderrs(0))


def test_bad_shapes_raise_named_error():
    with pytest.raises(FitError, match="y has 5 samples per trial but t has 4"):
        fit_trials(np.zeros((2, 5)), np.arange(4) / 1e3, (0.0, 0.002))


def test_non_finite_jacobian_is_a_status_not_a_crash():
    # Regression: one trial's non-finite Jacobian crashed eigvalsh and sank the batch.
    from frictionfit.fit._stats import statistics, status_of
    from frictionfit.models import get_model

    model = get_model("elastic_plastic")
    p = model.n_params
    u = np.zeros((2, p))
    resid = np.full((2, 50), 0.1)
    jac = np.ones((2, 50, p)) + np.arange(p) * np.linspace(0, 1, 50)[:, None]
    jtj = np.einsum("inp,inq->ipq", jac, jac)
    jtj[0, 1, 1] = np.nan
    mask = np.ones((2, 50), dtype=bool)
    stats = statistics(model, u, resid, jtj, mask)
    assert stats["flags"][0]["k"] == "singular" and np.isnan(stats["stderr"][0]["k"])
    assert status_of(p, True, u[0], stats["chi2"][0], stats["cond"][0], mask[0]) is Status.NONFINITE
    assert np.isfinite(stats["chi2"][1])


def test_ar1_deviance_is_unit_free_and_whitens_correlated_residuals():
    from frictionfit.fit._stats import ar1_deviance

    rng = np.random.default_rng(0)
    n = 4000
    e = rng.standard_normal((2, n))
    r = e.copy()
    for i in range(1, n):  # trial 1: AR(1) with rho = 0.7, unit marginal variance
        r[1, i] = 0.7 * r[1, i - 1] + np.sqrt(1 - 0.49) * e[1, i]
    mask = np.ones_like(r, dtype=bool)
    dev = ar1_deviance(r, mask)
    # Rescaling the force (N -> mN) shifts every member's deviance alike: BIC
    # differences do not depend on units (the former n_eff * log(chi2/n) did).
    assert np.allclose(ar1_deviance(1e3 * r, mask) - dev, n * np.log(1e6))
    white = n * np.log(np.mean(r**2, axis=1))
    assert abs(dev[0] - white[0]) < 5.0  # white residuals: the ordinary deviance
    # coloured: the likelihood gain of whitening is about -n log(1 - rho^2) = 0.67 n
    assert 0.6 * n < white[1] - dev[1] < 0.75 * n
    gappy = mask.copy()
    gappy[:, 1000:1100] = False  # a gap restarts the recurrence; no NaN, no crash
    assert np.all(np.isfinite(ar1_deviance(np.where(gappy, r, 0.0), gappy)))


def _unseen_relaxation():
    """Statistics of two ``relaxation`` trials with a 1 % relaxation, unseen in the first
    (its ``J^T J`` entry near 0) and well determined in the second; the model and ``u``."""
    from frictionfit.fit._stats import statistics
    from frictionfit.models import PARAMS, get_model

    model = get_model("relaxation")
    names = model.param_names
    u = np.array([[PARAMS[n].to_unconstrained(PARAMS[n].default) for n in names]] * 2)
    u[:, names.index("relax_frac")] = PARAMS["relax_frac"].to_unconstrained(0.01)
    jtj = np.stack([np.eye(len(names)) * 1e4] * 2)
    jtj[0, names.index("relax_frac"), names.index("relax_frac")] = 1e-6  # relaxation unseen
    mask = np.ones((2, 100), dtype=bool)
    return statistics(model, u, np.full((2, 100), 0.01), jtj, mask), model, u


def test_shape_of_an_unseen_effect_is_flagged():
    # tau only shapes the relaxation: when relax_frac is not told apart from 0, tau is
    # not identifiable, however small its own stderr (tau_below_sample, gallery seed 1).
    stats, _, _ = _unseen_relaxation()
    assert stats["flags"][0]["tau"].startswith("relax_frac not distinguishable")
    assert "tau" not in stats["flags"][1] and "relax_frac" not in stats["flags"][1]


def test_stiffness_loaded_within_a_sample_is_only_a_lower_bound():
    from frictionfit.fit._stats import flag_fast_loading

    base = dict(f_kin=0.8, f_static_excess=0.4, ramp=0.12)
    values = [dict(base, k=5000.0), dict(base, k=15.0), dict(base, k=0.5)]  # last: never slips
    flags = [{}, {}, {}]
    flag_fast_loading(flags, values, dt=1e-3, stroke_mm=1.0)
    assert flags[0]["k"].startswith("loads within 1.2 samples") and flags[1] == flags[2] == {}


def test_multi_start_jitter_is_per_trial_not_per_batch():
    from frictionfit.fit._guess import multi_starts, trial_keys
    from frictionfit.models import get_model

    ts = simulate_trials("elastic_plastic", 3, seed=8)
    model = get_model("elastic_plastic")
    u0 = np.zeros((3, model.n_params))
    keys = trial_keys(ts.y)
    all3 = multi_starts(model, u0, 4, seed=1, keys=keys)
    last_alone = multi_starts(model, u0[2:], 4, seed=1, keys=keys[2:])
    assert np.array_equal(all3[:, 2], last_alone[:, 0])
    assert not np.array_equal(all3[1:, 0], all3[1:, 1])
    assert np.array_equal(trial_keys(ts.y[[2, 0]]), keys[[2, 0]])
    # End to end: the same trial with other batch mates gives the same optimum, up to
    # the last bits XLA's lanes may round differently in another batch shape.
    kw = dict(model="elastic_plastic", chunk_size=4, n_starts=3, seed=3)
    a = fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), **kw)
    b = fit_trials(ts.y[[2, 0]], ts.t, (ts.t_out, ts.t_back), **kw)
    np.testing.assert_allclose(np.stack(b.u), np.stack(a.u)[[2, 0]], rtol=1e-12, atol=1e-12)
    assert np.array_equal(b.n_steps, a.n_steps[[2, 0]])


def test_clipped_channel_is_saturated_not_confident():
    from frictionfit.fit._guess import SATURATED_RUN, saturated_samples

    ts = simulate_trials("stick_slip", 2, seed=3, snr_db=30.0)
    y = ts.y.copy()
    mid = np.median(y[0, :40])  # the offset, before the out command
    level = 0.8 * np.max(np.abs(y[0] - mid))  # an amplifier clipping at 80% of the peak
    y[0] = np.clip(y[0], mid - level, mid + level)
    marked = saturated_samples(y)
    assert marked[0].sum() >= SATURATED_RUN and not marked[1].any()
    # quantised noise repeats values, but not in long runs at the extreme
    rng = np.random.default_rng(0)
    assert not saturated_samples(np.round(rng.normal(0, 2e-3, (4, 2000)), 3)).any()
    assert not saturated_samples(np.full((1, 50), 0.7)).any()  # a dead channel: not clipped
    res = fit_trials(y, ts.t, (ts.t_out, ts.t_back), model="stick_slip", chunk_size=8)
    assert Status(int(res.status[0])) is Status.SATURATED
    assert "saturated" in Status.SATURATED.message
    assert Status(int(res.status[1])) is not Status.SATURATED


@pytest.mark.slow
def test_auto_selection_picks_the_generating_member():
    # Measured on 32 trials/member at 20 dB with the AR(1) likelihood BIC: 32/32
    # for each member on the design seed 5, see the commit for fresh seeds.
    # 8 stick-slip trials here (the member the former rule missed most: 26/32).
    ts = simulate_trials("stick_slip", 8, seed=5)
    res = fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model="auto", chunk_size=8)
    assert list(res.bic_table.columns) == ["elastic_plastic", "stick_slip", "relaxation", "rich"]
    assert sum(m == "stick_slip" for m in res.model) >= 7, res.model
    assert "[[BIC by model]]" in fit_report(res, 0)


def test_a_new_covariance_re_flags_what_depends_on_the_standard_errors():
    # the flags a covariance sets ("stderr > value", a shape whose effect is not told from
    # none) follow it both ways; the others ("at bound", trade-offs) stay
    from frictionfit.fit._stats import WIDER, set_covariance

    stats, model, u = _unseen_relaxation()
    names = model.param_names
    assert stats["flags"][0]["tau"].startswith("relax_frac not distinguishable")
    tight, loose = np.eye(len(names)) * 1e-8, np.eye(len(names)) * 1e4
    set_covariance(model, u, stats, tuple(range(len(names))), np.stack([tight, loose]))
    assert "tau" not in stats["flags"][0] and "relax_frac" not in stats["flags"][0]
    assert stats["flags"][1]["k"] == WIDER
    np.testing.assert_allclose(stats["cov"][1], loose)
    assert stats["stderr"][0]["k"] < 1e-3 * stats["values"][0]["k"]
