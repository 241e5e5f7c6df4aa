"""Whole-measurement fits: the rig's drive, the data preparation, truth recovery, the CLI."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import frictionfit.fit._law_choice as law_choice
import frictionfit.fit._whole_batch as whole_batch
import frictionfit.fit.measurement as measurement
from frictionfit.cli import app
from frictionfit.errors import Status
from frictionfit.fit import fit_report, measurement_data
from frictionfit.fit._numerics import normal_equations, scaled_condition
from frictionfit.fit._whole_batch import (
    PROFILE_MIN_DROP,
    _faster_branch_first,
    _ridges_checked,
    _solver_jtj,
)
from frictionfit.fit._whole_problem import normal_fn, residual_fn, stack_items
from frictionfit.fit.session import read_session_rigs, write_session_rigs
from frictionfit.models import PARAMS, MeasurementModel
from frictionfit.models.measurement import to_unconstrained, trapezoid
from frictionfit.recording import read_recording, write_recording
from frictionfit.simulation.materials import CLASSES
from frictionfit.simulation.measurements import (
    measurement_truth,
    motor_profile,
    simulate_measurements,
)
from frictionfit.whole_fit import fit_recordings


@pytest.mark.parametrize("accel", [0.05, 0.2, 0.45])
def test_trapezoid_matches_the_simulated_motor(accel):
    t = np.linspace(-0.1, 0.3, 4001)
    pos, vel = trapezoid(jnp.asarray(t / 0.12), accel)
    want_pos, want_vel = motor_profile(t, 0.0, 0.12, accel * 0.12)
    np.testing.assert_allclose(np.asarray(pos), want_pos, atol=1e-12)
    np.testing.assert_allclose(np.asarray(vel) / 0.12, want_vel, rtol=1e-9, atol=1e-9)


@pytest.fixture(scope="module")
def simulated():
    specs = [(1, "carpet-1", 1), (1, "paper-2", 1), (2, "floor-mat-1", 1), (2, "scarf-1", 1),
             (1, "cushion-1", 1), (2, "pe-bag-2", 1)]
    return simulate_measurements(specs, seed=5)


def test_data_masks_faults_and_the_preparatory_motion(simulated):
    rec = simulated[0]
    y = rec.samples.copy()
    y[3000:3010, 2] = np.nan
    spike = int(np.argmin(np.abs(rec.t - 4.0)))
    y[spike, 2] += 30.0  # a transmission spike
    rec = type(rec)(rec.t, y, rec.sample_rate_hz, rec.channels, events=rec.events,
                    metadata=rec.metadata, truth=rec.truth, name=rec.name)
    d = measurement_data(rec, "index_x", decimate=2)
    t = d.t
    assert np.all(np.diff(t) > 0)
    moving = (t > 2.1) & (t < 2.3)  # fine blocks while the finger moves, coarse while it holds
    holding = (t > 2.5) & (t < 2.9)
    assert np.median(np.diff(t[moving])) == pytest.approx(0.002)
    assert np.median(np.diff(t[holding])) == pytest.approx(0.010)
    assert not d.mask[t < 2.05].any()  # motion 0 sets the state, is not fitted
    assert not d.mask[(t > 3.0) & (t < 3.01)].any()
    at = int(np.argmin(np.abs(t - 4.0)))
    assert abs(d.y[at] - np.median(d.y[at - 3:at + 4])) < 0.1  # the spike left out
    assert d.mask[(t > 2.1) & (t < 2.9)].all()
    assert np.all(np.isfinite(d.y))
    with pytest.raises(ValueError, match="no channel 'wrist_x'"):
        measurement_data(rec, "wrist_x")


def test_relabelled_branches_predict_the_same_force():
    model = MeasurementModel("relaxation2")
    u = to_unconstrained(model, {"k": 8.0, "f_kin": 1.0, "f_static_excess": 0.3,
                                 "relax_frac": 0.2, "tau": 1.2, "relax_frac2": 0.5, "tau2": 0.1})
    swapped, relabelled = _faster_branch_first(model, u[None])
    swapped = swapped[0]
    assert relabelled.tolist() == [True]
    v = model.physical(swapped)
    assert v["tau"] < v["tau2"]
    t = jnp.arange(4000) / 1000.0
    cmd, signs = jnp.array([0.05, 1.05, 2.05, 3.05]), jnp.array([1.0, -1.0, 1.0, -1.0])
    np.testing.assert_allclose(model.predict(jnp.asarray(swapped), t, cmd, signs, 1.0),
                               model.predict(jnp.asarray(u), t, cmd, signs, 1.0), atol=1e-9)


def _one_motion():
    """A ``relaxation2`` model, a point in its unconstrained coordinates, and one out-back
    motion's times and commands (s) and signs. The samples miss the drive's kinks (at a
    kink JAX's derivative is the mean of both sides', the compiled loop's one side's)."""
    model = MeasurementModel("relaxation2")
    u = jnp.asarray(to_unconstrained(model, {"k": 8.0, "f_kin": 1.0, "f_static_excess": 0.3,
                                             "relax_frac": 0.2, "tau": 0.1, "delay": 0.01}))
    t = (jnp.arange(2500) + 0.37) / 1000.0
    return model, u, t, jnp.array([0.05, 1.05]), jnp.array([1.0, -1.0])


def test_holding_the_rig_leaves_the_other_derivatives_unchanged():
    model, u, t, cmd, signs = _one_motion()
    rig = ("delay", "ramp", "accel")
    full = jax.jacfwd(lambda w: model.predict(w, t, cmd, signs, 1.0))(u)
    held = jax.jacfwd(lambda w: model.predict(w, t, cmd, signs, 1.0, rig))(u)
    free = [j for j, n in enumerate(model.param_names) if n not in rig]
    assert np.abs(full[:, free]).max() > 0
    np.testing.assert_allclose(held[:, free], full[:, free], rtol=1e-10, atol=1e-12)
    at_rig = [model.param_names.index(n) for n in rig]  # a held parameter's derivative: 0
    assert np.abs(full[:, at_rig]).max() > 0 and not np.asarray(held[:, at_rig]).any()


def test_the_models_jacobian_through_the_compiled_loop_is_the_plain_simulations():
    # predict's derivative (the loop, behind a custom JVP) against the plain scan's, whose
    # derivative JAX takes itself (timing_derivatives=True), at every parameter, batched as
    # the fits' pools call it.
    model, u, t, cmd, signs = _one_motion()
    loop = jax.jit(jax.vmap(jax.jacfwd(lambda w: model.predict(w, t, cmd, signs, 1.0))))
    scan = jax.jit(jax.vmap(jax.jacfwd(lambda w: model.predict(
        w, t, cmd, signs, 1.0, timing_derivatives=True))))
    us = jnp.stack([u, u + 0.05, u - 0.05])
    want = scan(us)
    assert np.abs(want).max(axis=(0, 1)).min() > 0
    np.testing.assert_allclose(loop(us), want, rtol=1e-10, atol=1e-12 * np.abs(want).max())


@pytest.mark.parametrize(("law", "held"), [("relaxation2", ()), ("no_peak2", ("delay", "ramp",
                                                                            "accel")),
                                           ("relaxation2", ("offset", "tau2"))])
def test_the_fits_normal_equations_are_those_of_the_residuals_jacobian(simulated, law, held):
    # the solver's normal equations, summed in the compiled loop, against J^T J and J^T r
    # of the residual's forward-mode Jacobian (priors included), a padded batch, held
    # parameters (a held rig leaves the contact's rig lanes out)
    model = MeasurementModel(law)
    items = [measurement_data(rec, ch) for rec in simulated[:2] for ch in ("index_x", "thumb_x")]
    items[1] = dataclasses.replace(items[1], t=items[1].t[:-50], y=items[1].y[:-50],
                                   weight=items[1].weight[:-50])
    u0 = np.stack([to_unconstrained(model, d.guess) for d in items])
    data = stack_items(items, u0)
    free = tuple(j for j, n in enumerate(model.param_names) if n not in held)
    residual = residual_fn(model, free)
    want = jax.vmap(lambda u, d: normal_equations(lambda z: residual(z, d), u))(
        u0[:, list(free)], data)
    got = jax.vmap(normal_fn(model, free))(u0[:, list(free)], data)
    assert np.all(np.diagonal(want[1], axis1=1, axis2=2) > 0)  # every free parameter acts
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-10, atol=1e-12 * np.abs(w).max())


@pytest.mark.parametrize("law", ["no_peak2", "relaxation2"])
def test_the_movement_timings_normal_equations_are_those_of_jax(simulated, law):
    # the compiled loop's normal equations in every movement's onset shift and log
    # duration factor, against jacfwd of the plain scan (timing_derivatives=True), at a
    # jittered timing
    model = MeasurementModel(law)
    d = measurement_data(simulated[1], "index_x")
    u = jnp.asarray(to_unconstrained(model, d.guess))
    rng = np.random.default_rng(3)
    cmd = d.commands + rng.normal(0.0, 0.002, d.commands.size)
    stretch = np.exp(rng.normal(0.0, 0.03, d.commands.size))
    m = cmd.size

    def resid(z):
        pred = model.predict(u, d.t, cmd + z[:m], d.signs, d.direction,
                             stretch=stretch * jnp.exp(z[m:]), timing_derivatives=True)
        return d.weight * (pred - d.y)

    want = normal_equations(resid, jnp.zeros(2 * m))
    got = model.timing_normal_equations(u, d.t, cmd, d.signs, stretch, d.direction, d.y,
                                        d.weight)
    assert np.all(np.diagonal(want[1])[np.tile(d.signs != 0, 2)] > 0)  # each timing acts
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-10, atol=1e-12 * np.abs(w).max())


@pytest.mark.parametrize(("scale", "lifted"), [(4.0, True), (0.01, False)])
def test_a_trade_off_is_lifted_only_where_the_posterior_is_no_wider_than_its_gaussian(
        simulated, scale, lifted):
    """A covariance ``scale`` times the likelihood's curvature: 2 sd out on a profile line
    the log posterior then drops by about ``2 scale``; wider than the data say (4) lifts
    the flags, narrower keeps them (the data's posterior would be wider than the reported
    interval)."""
    model = MeasurementModel("no_peak2")
    res = fit_recordings(simulated[0], channels=["index_x"], model=model, progress=False)
    free = tuple(range(len(model.param_names)))
    u = np.stack(res.u)
    data = stack_items(res.items, u)
    jtj = _solver_jtj(model, free, u, data, np.full((1, len(free), len(free)), np.nan),
                      np.ones(1, bool))  # computed at u
    # a parameter the data do not inform (its Jacobian column zero: at its bound) has no
    # profile line; whether it is lifted would be decided by the rounding of pinv
    names = [n for j, n in enumerate(model.param_names) if jtj[0, j, j] > 0]
    assert len(names) >= len(free) - 2
    stats = {"flags": [{n: "trades off with k" for n in names if n != "k"} | {"k": "at bound"}],
             "cov": scale * res.cov[0][None], "values": [res.params(0)],
             "stderr": [res.stderrs(0)]}
    _ridges_checked(model, free, u, stats, data, res.noise_var)
    kept = [n for n, f in stats["flags"][0].items() if f.startswith("trades off")]
    assert stats["flags"][0]["k"] == "at bound"  # other flags untouched
    assert 2 * scale > PROFILE_MIN_DROP if lifted else 2 * scale < PROFILE_MIN_DROP
    assert kept == ([] if lifted else [n for n in names if n != "k"])


def test_recovers_stiffness_and_friction_of_simulated_measurements(simulated):
    items = [measurement_data(r, "index_x") for r in simulated]
    res = fit_recordings(items, progress=False)
    assert all(Status(int(s)) in (Status.CONVERGED, Status.ILL_CONDITIONED) for s in res.status)
    err = {}
    for name in ("k", "f_kin"):
        truth = [measurement_truth(r, name) for r in simulated]
        fitted = res.values[name].to_numpy()
        err[name] = np.median(np.abs(fitted / np.array(truth) - 1))
    # measured on these six: k 0.03, f_kin 0.01 (per-motion fits: k off by 50x)
    assert err["k"] < 0.10 and err["f_kin"] < 0.05, err
    assert np.all(res.r2 > 0.99)
    d = items[0]  # the result recomputes its curve: the weighted R^2 it reports
    pred = res.predict(0, d.t)
    w2 = d.weight**2
    y_bar = np.sum(w2 * d.y) / np.sum(w2)
    r2 = 1 - np.sum(w2 * (pred - d.y) ** 2) / np.sum(w2 * (d.y - y_bar) ** 2)
    assert r2 == pytest.approx(res.r2[0], rel=1e-9)
    # the kept covariance is the one the standard errors come from (delta method)
    names = res.free_names(0)
    assert res.cov[0].shape == (len(names), len(names)) and "offset" in names
    j, h = names.index("k"), 1e-6
    u_k = res.u[0][MeasurementModel(res.model[0].removeprefix("measurement-")).param_names
                   .index("k")]
    slope = (PARAMS["k"].to_physical(u_k + h) - PARAMS["k"].to_physical(u_k - h)) / (2 * h)
    assert res.stderr["k"][0] == pytest.approx(abs(slope) * np.sqrt(res.cov[0][j, j]), rel=1e-5)


def test_each_movements_latency_and_duration_found(simulated):
    """Data from the model itself, every movement with its own onset and duration, friction
    falling as the textile wears: the fit finds the timing, and the law."""
    rec = simulated[0]
    commands, signs = measurement_data(rec, "index_x").drive[:2]
    model = MeasurementModel("relaxation2")
    truth = {"k": 8.0, "f_kin": 1.0, "f_static_excess": 0.3, "relax_frac": 0.3, "tau": 0.08,
             "relax_frac2": 0.1, "tau2": 1.0, "wear": 0.01, "delay": 0.02, "ramp": 0.12}
    rng = np.random.default_rng(3)
    shift = rng.uniform(-0.004, 0.004, commands.size)
    stretch = np.exp(rng.uniform(-0.05, 0.05, commands.size))
    y = model.predict(jnp.asarray(to_unconstrained(model, truth)), rec.t, commands + shift,
                      signs, 1.0, stretch=stretch)
    samples = rec.samples.copy()
    samples[:, rec.channel_names.index("index_x")] = y + 0.002 * rng.standard_normal(y.size)
    d = measurement_data(dataclasses.replace(rec, samples=samples), "index_x")
    res = fit_recordings([d], model=model, progress=False)
    found_commands, found_stretch = res.items[0].commands, res.items[0].stretch
    fitted = slice(2, None)  # the first motion is simulated, not fitted
    fit = res.params(0)
    onset = found_commands + fit["delay"] - (commands + shift + truth["delay"])
    assert np.max(np.abs(onset[fitted])) < 0.0005, onset  # s
    duration = found_stretch * fit["ramp"] / (stretch * truth["ramp"])
    assert np.max(np.abs(duration[fitted] - 1)) < 0.01, duration
    for name in ("k", "f_kin", "f_static_excess", "relax_frac", "tau"):
        assert fit[name] == pytest.approx(truth[name], rel=0.03), name
    assert fit["wear"] == pytest.approx(truth["wear"], abs=0.001)  # 1/mm


def test_cli_fits_whole_recordings_by_default(tmp_path, simulated, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write_recording(simulated[1], tmp_path / "one")
    out, plots = tmp_path / "whole.csv", tmp_path / "png"
    run = CliRunner().invoke(app, ["fit", str(tmp_path / "one.csv"), "--channel", "index_x",
                                   "--model", "relaxation2", "--fix", "drift=0",
                                   "--uncertainty", "laplace",
                                   "--plot", str(plots), "--out", str(out), "--report"])
    assert run.exit_code == 0, run.output
    assert "[[Correlations]]" in run.output
    import pandas as pd

    frame = pd.read_csv(out)
    assert frame["trial"].tolist() == ["one/index_x"]
    assert frame["k [N/stroke]"].notna().all()  # no stroke declared: no false N/mm
    assert not [c for c in frame.columns if "mm]" in c]
    assert frame["drift_flag"].tolist() == ["fixed"] and frame["drift [N/s]"].tolist() == [0.0]
    assert frame["uq_method"].tolist() == ["laplace"]  # the posterior's quantiles beside
    k = frame.iloc[0][["k_p2.5 [N/stroke]", "k_median [N/stroke]",
                       "k_p97.5 [N/stroke]"]].to_numpy()
    assert k[0] < frame["k [N/stroke]"][0] < k[2] and np.all(np.diff(k) > 0)
    assert k[0] < measurement_truth(simulated[1], "k") < k[2]
    assert [p.name for p in plots.iterdir()] == ["one__index_x.png"]
    bad = CliRunner().invoke(app, ["fit", str(tmp_path / "one.csv"), "--tie", "k",
                                   "--out", str(out), "--overwrite"])
    assert bad.exit_code != 0 and "per-motion fits only: add --motions" in bad.output
    bad = CliRunner().invoke(app, ["fit", str(tmp_path / "one.csv"), "--uncertainty", "mcmc",
                                   "--out", str(out), "--overwrite"])
    assert bad.exit_code != 0 and "choose none, laplace, emcee or auto" in bad.output
    bad = CliRunner().invoke(app, ["fit", str(tmp_path / "one.csv"), "--fix", "stiffness=1",
                                   "--out", str(out), "--overwrite"])
    assert bad.exit_code != 0 and "cannot fix ['stiffness']" in bad.output
    bad = CliRunner().invoke(app, ["fit", str(tmp_path / "one.csv"), "--rig", "motor",
                                   "--out", str(out), "--overwrite"])
    assert bad.exit_code != 0 and "choose recording or session" in bad.output


def test_a_dead_channel_is_named_and_the_others_fitted(tmp_path, simulated):
    rec = simulated[1]
    samples = rec.samples.copy()
    samples[:, rec.channel_names.index("index_x")] = 0.1
    dead = dataclasses.replace(rec, samples=samples, name="dead")
    with pytest.raises(ValueError, match=r"dead: channel 'index_x' is constant at 0\.1 N "
                                         r"\(a dead sensor\?\): no force to fit"):
        measurement_data(dead, "index_x")
    write_recording(dead, tmp_path / "dead")
    out = tmp_path / "fits.csv"
    run = CliRunner().invoke(app, ["fit", str(tmp_path / "dead.csv"), "--model", "no_peak2",
                                   "--out", str(out)])
    assert run.exit_code == 0, run.output
    assert "skipped dead: channel 'index_x' is constant at 0.1 N" in run.output
    frame = pd.read_csv(out)
    assert frame["trial"].tolist() == ["dead/thumb_x"] and frame["status"][0] == "converged"
    alone = CliRunner().invoke(app, ["fit", str(tmp_path / "dead.csv"), "--channel", "index_x",
                                     "--out", str(out), "--overwrite"])
    assert alone.exit_code == 2 and "no recording could be fitted" in alone.output


def test_moves_without_targets_alternate_out_and_back(simulated):
    rec = simulated[1]
    bare = dataclasses.replace(rec, events=tuple(dataclasses.replace(e, target=None)
                                                 for e in rec.events))
    with_targets, without = measurement_data(rec, "index_x"), measurement_data(bare, "index_x")
    # every move had been "out" (k 0.25 against 41 N/mm on the sample, "converged")
    np.testing.assert_array_equal(without.signs, with_targets.signs)
    np.testing.assert_array_equal(without.signs[:4], [1.0, -1.0, 1.0, -1.0])


def test_a_clipped_channel_is_fitted_without_its_clipped_runs_and_says_so(simulated):
    rec = simulated[1]
    samples = rec.samples.copy()
    j = rec.channel_names.index("index_x")
    samples[:, j] = np.minimum(samples[:, j], np.nanquantile(samples[:, j], 0.95))
    item = measurement_data(dataclasses.replace(rec, samples=samples), "index_x")
    assert item.clipped > 100
    assert measurement_data(rec, "index_x").clipped == 0
    result = fit_recordings([item], model="no_peak2")
    assert Status(result.status[0]) == Status.SATURATED


def test_samples_the_daq_flagged_overloaded_are_left_out_and_said(simulated):
    rec = simulated[1]
    first = int(np.argmax(rec.t >= 3.0))
    runs = [{"channel": "index_x", "t": float(rec.t[first]), "samples": 150},
            {"channel": "thumb_x", "t": 1.0, "samples": 40}, {"channel": "nope", "t": 0.0}]
    flagged = dataclasses.replace(rec, extra={**rec.extra, "acquisition": {"overloads": runs}})
    mask = flagged.overloaded("index_x", rec.t)
    assert mask.sum() == 150 and mask[first] and not mask[first - 1]
    assert measurement_data(flagged, "index_x").clipped == 150
    assert measurement_data(rec, "index_x").clipped == 0
    result = fit_recordings([measurement_data(flagged, "index_x")], model="no_peak2")
    assert Status(result.status[0]) == Status.SATURATED
    from frictionfit.features._base import content_key

    assert content_key(flagged) != content_key(rec)  # cached features are not reused


def test_a_recording_cut_short_is_fitted_from_what_it_holds(tmp_path, simulated):
    from frictionfit.datasets.rubbing_lab import load
    from frictionfit.recording import DatasetWarning

    rec = simulated[1]
    for name, end_s in (("cut6", 6.5), ("cut3", 3.5)):
        keep = rec.t < end_s
        write_recording(dataclasses.replace(rec, t=rec.t[keep], samples=rec.samples[keep],
                                            name=name), tmp_path / name)
    out = tmp_path.parent / f"{tmp_path.name}-fits.csv"
    run = CliRunner().invoke(app, ["fit", str(tmp_path / "cut6.csv"), "--channel", "index_x",
                                   "--model", "no_peak2", "--out", str(out)])
    assert run.exit_code == 0, run.output
    frame = pd.read_csv(out)
    assert frame["status"].tolist() == ["converged"] and "[ends_early]" in frame["problems"][0]
    # a folder keeps the recording that holds complete motions, names the one that does not
    with pytest.warns(DatasetWarning, match=r"skipped cut3: it ends at t=3\.499 s, before a "
                                             "complete motion after the preparatory one"):
        assert [r.name for r in load(tmp_path)] == ["cut6"]


def test_cli_holds_the_rig_of_each_session(tmp_path, simulated, monkeypatch):
    monkeypatch.chdir(tmp_path)
    day_one = [r for r in simulated if r.metadata["session"] == 1][:2]
    for k, rec in enumerate(day_one):
        write_recording(rec, tmp_path / f"r{k}")
    out = tmp_path.parent / f"{tmp_path.name}-session.csv"  # not in the folder fitted
    run = CliRunner().invoke(app, ["fit", str(tmp_path), "--channel", "index_x", "--model",
                                   "relaxation2", "--rig", "session", "--out", str(out)])
    assert run.exit_code == 0, run.output
    import pandas as pd

    frame = pd.read_csv(out)
    for name in ("ramp", "accel"):  # one motor profile for the day: held, the same for both
        column = next(c for c in frame.columns if c.startswith(f"{name} ["))
        assert frame[f"{name}_flag"].tolist() == ["fixed", "fixed"]
        assert frame[column].nunique() == 1
    assert (frame["delay_flag"] != "fixed").all()  # the latency stays each recording's
    # the day's profile saved, a recording fitted later on its own holds it
    rigs = tmp_path.parent / f"{tmp_path.name}-rigs.json"
    run = CliRunner().invoke(app, ["fit", str(tmp_path), "--channel", "index_x", "--model",
                                   "relaxation2", "--rig", "session", "--save-rig", str(rigs),
                                   "--out", str(out), "--overwrite"])
    assert run.exit_code == 0, run.output
    later = tmp_path.parent / f"{tmp_path.name}-later.csv"
    run = CliRunner().invoke(app, ["fit", str(tmp_path / "r0.csv"), "--channel", "index_x",
                                   "--model", "relaxation2", "--rig", str(rigs), "--out",
                                   str(later)])
    assert run.exit_code == 0, run.output
    k = next(c for c in frame.columns if c.startswith("k ["))
    assert pd.read_csv(later)[k][0] == pytest.approx(frame[k][0], rel=1e-6)
    bad = CliRunner().invoke(app, ["fit", str(tmp_path), "--save-rig", str(rigs), "--out",
                                   str(out), "--overwrite"])
    assert bad.exit_code != 0 and "estimated with --rig session" in bad.output


def test_session_rig_holds_the_motor_of_each_day(simulated, tmp_path):
    items = [measurement_data(r, "index_x") for r in simulated]
    res = fit_recordings(items, rig="session", progress=False)
    sessions = np.array([d.session for d in items])
    day = {s: f"{simulated[0].metadata['rig']}/{s}" for s in (1, 2)}  # a session of its rig
    for name in ("ramp", "accel"):
        values = res.values[name].to_numpy()
        for s in (1, 2):
            assert np.ptp(values[sessions == day[s]]) == 0.0  # one motor profile per day
        assert all(f[name] == "fixed" for f in res.flags)
    assert not any(f.get("delay") == "fixed" for f in res.flags)  # latency per recording
    assert np.ptp(res.values["delay"].to_numpy()[sessions == day[1]]) > 0.0
    truth = [measurement_truth(r, "ramp") for r in simulated]
    np.testing.assert_allclose(res.values["ramp"], truth, rtol=0.05)
    # the day's profiles, saved, hold a recording fitted later on its own: the same numbers
    assert sorted(res.session_rigs) == [day[1], day[2]]
    assert all(r.n_fits >= 2 for r in res.session_rigs.values())
    write_session_rigs(res.session_rigs, tmp_path / "rigs.json")
    rigs = read_session_rigs(tmp_path / "rigs.json")
    assert rigs == res.session_rigs
    later = fit_recordings(items[:1], rig=rigs, progress=False)
    for name in ("k", "f_kin", "ramp", "accel"):
        assert later.values[name][0] == pytest.approx(res.values[name][0], rel=1e-6)
    for name in ("k", "f_kin"):
        assert later.stderr[name][0] == pytest.approx(res.stderr[name][0], rel=1e-6)
    with pytest.raises(ValueError, match="no motor profile for session"):
        fit_recordings(items[:1], rig={"7": rigs[day[1]]})
    (tmp_path / "bad.json").write_text('{"1": {"ramp": 0.1}}')
    with pytest.raises(ValueError, match="not a file of session motor profiles"):
        read_session_rigs(tmp_path / "bad.json")


def test_two_rigs_sessions_numbered_alike_hold_two_motors():
    from frictionfit.simulation.rigs import rig_for

    recs = [r for rig in ("sim-a", "sim-b")
            for r in simulate_measurements([(1, c, 1) for c in CLASSES[:2]], seed=2,
                                           rig=rig_for(rig))]
    res = fit_recordings([measurement_data(r, "index_x") for r in recs], rig="session",
                         progress=False)
    assert sorted(res.session_rigs) == ["sim-a/1", "sim-b/1"]
    ramp = res.values["ramp"].to_numpy()
    assert ramp[0] == ramp[1] != ramp[2] == ramp[3]  # sim-b's motor is slower


def test_a_held_profile_keeps_its_own_uncertainty(simulated):
    # alone in its session, a recording holds its own profile: the stiffness's stderr is
    # then about its free fit's (the held values' covariance carried into it), not the
    # narrower one of a fit that takes the profile as known. The held share is first order
    # and treats the session's profile as independent of the recording: here it is the
    # recording's own estimate, so the share overstates (by up to a third)
    item = [measurement_data(simulated[0], "index_x")]
    kw = dict(model="relaxation2", progress=False)
    alone = fit_recordings(item, rig="session", **kw)
    free = fit_recordings(item, **kw)
    known = fit_recordings(item, fix={n: alone.values[n][0] for n in ("ramp", "accel")},
                             **kw)
    assert alone.flags[0]["ramp"] == "fixed"
    assert known.stderr["k"][0] < 0.95 * free.stderr["k"][0]  # the profile matters to k
    assert free.stderr["k"][0] < alone.stderr["k"][0] < 1.33 * free.stderr["k"][0]
    with pytest.raises(ValueError, match="a session's profile holds ramp, accel"):
        fit_recordings(item, rig="session", fix={"ramp": 0.12})


def test_a_slow_branch_pinned_at_its_bound_is_solved_again(simulated, monkeypatch):
    # started with the slow branch at its largest fraction, the solver stays there (the
    # logistic map is flat); solved again from a weaker, faster branch, each fit is better
    items = [measurement_data(r, "index_x") for r in simulated]
    model = MeasurementModel("relaxation2")
    u0 = np.stack([to_unconstrained(model, d.guess | {"relax_frac2": 0.95, "tau2": 8.0})
                   for d in items])
    kw = dict(model=model, fix=None, u0=u0, max_steps=400, pool_size=16, progress=False,
              solver=measurement.WHOLE_FIT_SOLVER)
    again = whole_batch.fit_batch(items, **kw)
    monkeypatch.setattr(whole_batch, "_slow_branch_restarted",
                        lambda model, items, solve, u, *rest: np.zeros(len(u), bool))
    pinned = whole_batch.fit_batch(items, **kw)
    assert all(f["relax_frac2"] == "at bound" for f in pinned.flags)
    assert not any(f.get("relax_frac2") == "at bound" for f in again.flags)
    assert np.all(again.chi2 < pinned.chi2)


def test_fix_rejects_unknown_parameters(simulated):
    item = [measurement_data(simulated[0], "index_x")]
    with pytest.raises(ValueError, match="cannot fix"):
        fit_recordings(item, fix={"wobble": 1.0})
    with pytest.raises(ValueError, match="cannot fix"):  # a parameter of another law
        fit_recordings(item, model="relaxation2", fix={"damping": 1e-3})
    held = fit_recordings(item, model="rich", fix={"damping": 1e-3}, progress=False)
    assert held.values["damping"][0] == pytest.approx(1e-3)


def test_fix_refuses_values_it_cannot_hold(simulated):
    # a NaN once made every column vanish and crashed the batch; a value past a bound was
    # silently pulled inside it
    items = [measurement_data(r, "index_x") for r in simulated[:2]]
    name = f"{items[1].name}/index_x"
    with pytest.raises(ValueError, match=rf"cannot fix ramp at nan s for {name} \(1 of 2"):
        fit_recordings(items, fix={"ramp": [0.12, np.nan]})
    with pytest.raises(ValueError, match=r"cannot fix wear at 0.1 1/mm .* within \[-0.05, 0.05\]"):
        fit_recordings(items, fix={"wear": 0.1})
    with pytest.raises(ValueError, match="one value or one per item"):
        fit_recordings(items, fix={"ramp": [0.12, 0.12, 0.12]})


def test_condition_of_nothing_is_infinite():
    # every free parameter of a fit flagged (at a bound, or its column vanishing) leaves an
    # empty matrix: nothing is determined, and the batch goes on with a status
    assert np.all(scaled_condition(np.zeros((3, 0, 0))) == np.inf)
    assert whole_batch._cond_inside(np.eye(2), [False, False]) == np.inf


def test_auto_holds_a_value_in_the_laws_that_have_it(simulated):
    # a held peak has no standard error, so the law without a peak is fitted too: it lacks
    # the parameter and is fitted without it (this once raised "cannot fix")
    item = [measurement_data(simulated[0], "index_x")]
    res = fit_recordings(item, fix={"f_static_excess": 0.2, "damping": 1e-3}, progress=False)
    assert np.isfinite(res.bic_table.to_numpy()).all()  # every law fitted
    law = res.model[0].removeprefix("measurement-")
    held = {"no_peak2": {}, "relaxation2": {"f_static_excess": 0.2},
            "rich": {"f_static_excess": 0.2, "damping": 1e-3}}[law]
    for name, value in held.items():
        assert res.values[name][0] == pytest.approx(value) and res.flags[0][name] == "fixed"


def test_fitted_features_follow_the_sklearn_contract():
    from sklearn.base import clone

    from frictionfit.features.physical import FittedFeatures

    f = FittedFeatures(rig="recording", decimate=2)
    assert clone(f).get_params() == f.get_params()
    rubbing = ("k [log10 N/mm]", "f_static [log10 N]", "f_held [log10 N]", "f_peak [log10 N]",
               "onset_rate [log10 N/s]", "slip_noise [log10 N]")
    lateral = ("gain [1]", "slip_noise [log10 N]")  # the lateral law on the finger's force
    assert list(f.get_feature_names_out()) == [
        f"{finger}_{axis}:fit_{n}" for finger in ("thumb", "index")
        for axis, names in (("x", rubbing), ("y", lateral)) for n in names]


def test_single_motions_refitted_with_the_rig_and_sensor_held(simulated):
    whole = fit_recordings(simulated[:3], channels=["index_x"], model="relaxation2",
                           progress=False)
    motions = whole.per_motion()
    item_of, motion_of = motions.item_of, motions.motion_of
    assert motions.ids[0] == f"{simulated[0].name}/index_x#1"
    assert np.bincount(item_of).tolist() == [4, 4, 4]  # the preparatory motion is not refitted
    assert sorted(set(motion_of.tolist())) == [1, 2, 3, 4]
    fitted, true = [], []
    for r, (i, m) in enumerate(zip(item_of, motion_of, strict=True)):
        assert motions.values["ramp"][r] == whole.values["ramp"][i]
        assert motions.values["wear"][r] == whole.values["wear"][i]  # the measurement's trend
        # each motion's own friction (the simulator wears it by 1 % per motion, +-2 % jitter;
        # the refit refers it to the travel's halfway point, within ~2 % of the motion's),
        # where the refit converged and did not trade f_kin off (carpet's fast relaxation can)
        if motions.status[r] == Status.CONVERGED and "f_kin" not in motions.flags[r]:
            fitted.append(motions.values["f_kin"][r])
            true.append(simulated[i].truth["motions"][m]["channels"]["index_x"]["f_kin"])
    assert len(fitted) >= 9
    np.testing.assert_allclose(fitted, true, rtol=0.1)


def test_a_branch_that_no_longer_acts_does_not_make_the_fit_ill_conditioned(shared):
    """A lab channel whose second Maxwell branch settles at fraction 0: the branch's time has
    a vanishing column ("singular", flagged), which made ``J^T J`` singular (condition
    number ~1e17) although every other parameter is well determined."""
    d = measurement_data(read_recording(shared / "datasets" / "rubbing-lab"
                                        / "s1_place-mat-2_01.csv"), "thumb_x")
    res = fit_recordings([d], model="no_peak2", progress=False)
    assert res.flags[0].get("tau2") == "singular"
    assert Status(int(res.status[0])) == Status.CONVERGED and res.cond[0] < 1e6
    assert "k" not in res.flags[0] and "f_kin" not in res.flags[0]


def test_a_static_excess_cannot_stand_in_for_the_kinetic_level(shared):
    """A lab channel whose force droops a little over each slide (basket, one layer): with a
    slip-weakening length of up to 10 mm the fit put the level into a "static excess" that
    never weakened within a stroke (1.53 N over 10 mm) and the kinetic level at 0.036 N.
    A static peak weakens within the stroke, so the kinetic level carries the slide."""
    model = MeasurementModel()
    assert model.params[model.param_names.index("slip_length")].upper == model.stroke_mm
    assert PARAMS["slip_length"].upper == 10.0  # the family's, e.g. FabricSlide's long slides
    with pytest.raises(ValueError, match=r"slip_length: prior .* inside \(0.0001, 1\) mm"):
        model.with_priors({"slip_length": (5.0, 1.0)})  # refused where it is set, not in a fit
    d = measurement_data(read_recording(shared / "datasets" / "rubbing-lab"
                                        / "s1_basket-1_03.csv"), "index_x")
    res = fit_recordings([d], progress=False)
    assert Status(int(res.status[0])) == Status.CONVERGED
    # the basket's held level is ~1.5 N on this finger
    assert res.values.at[0, "f_kin"] > 1.0 and "f_kin" not in res.flags[0], res.params(0)


def test_damping_is_found_where_the_simulator_put_it(simulated):
    # "rich" is grown from relaxation2's optimum with the damping where it acts, and finds
    # the simulator's damping within a factor 1.5 (median over the six; its stderr is a
    # few tens of per cent of it on these)
    items = [measurement_data(r, "index_x") for r in simulated]
    truth = np.array([measurement_truth(r, "damping") for r in simulated])
    grown = fit_recordings(items, model="rich", progress=False)
    assert grown.model == ["measurement-rich"] * len(items)
    ratio = grown.values["damping"].to_numpy() / truth
    assert 0.5 < np.median(ratio) < 1.5, ratio


def _first_within_tie(table: pd.DataFrame) -> list[str]:
    """Per row, the first law whose BIC (of those fitted) is within 2 of the row's best."""
    rows = (row.dropna() for _, row in table.iterrows())
    return [next(c for c in row.index if row[c] <= row.min() + 2) for row in rows]


def test_auto_grows_rich_only_where_the_static_peak_is_chosen(simulated):
    items = [measurement_data(r, "index_x") for r in simulated]
    res = fit_recordings(items, progress=False)
    table = res.bic_table
    assert list(table.columns) == [f"measurement-{law}" for law in measurement.AUTO_LAWS]
    peak = np.isin(res.model, ["measurement-relaxation2", "measurement-rich"])
    assert np.array_equal(np.isfinite(table["measurement-rich"]), peak)
    assert res.model == _first_within_tie(table)


def test_auto_fits_the_law_without_a_peak_only_where_no_peak_is_measured(simulated, shared,
                                                                          monkeypatch):
    lab = shared / "datasets" / "rubbing-lab"
    items = [measurement_data(r, "index_x") for r in simulated[:2]] + [
        measurement_data(read_recording(lab / f"{name}.csv"), channel)
        for name, channel in (("s1_banknote-1_03", "thumb_x"), ("s1_basket-1_01", "index_x"),
                              ("s2_carpet-1_02", "thumb_x"))]
    calls, fit = [], measurement.fit_batch

    def spy(at, **kw):
        calls.append((kw["model"].law, fit(at, **kw)))
        return calls[-1][1]

    monkeypatch.setattr(measurement, "fit_batch", spy)
    res = fit_recordings(items, progress=False)
    assert [law for law, _ in calls] == ["relaxation2", "relaxation2", "no_peak2", "rich"]
    larger, smaller = calls[1][1], calls[2][1]
    fitted = ~law_choice.peak_measured([MeasurementModel("relaxation2")], [larger],
                                         [np.arange(len(items))], len(items))
    assert 0 < np.sum(fitted) < len(items)  # both kinds of item
    table = res.bic_table
    assert np.array_equal(np.isfinite(table["measurement-no_peak2"]), fitted)
    unfitted = int(np.flatnonzero(~fitted)[0])
    assert "measurement-no_peak2 none (not fitted" in fit_report(res, unfitted)
    # without a peak that weakens over many strokes, its force moves to the kinetic level
    # (the last item's 1.2-N peak weakens over 9 mm): the fit ends near the larger one's
    np.testing.assert_array_less(smaller.chi2, 1.1 * larger.chi2[fitted])
    peak = np.isin(res.model, ["measurement-relaxation2", "measurement-rich"])
    assert np.array_equal(np.isfinite(table["measurement-rich"]), peak)
    assert res.model == _first_within_tie(table)


def test_rich_without_a_second_fit_and_its_start(simulated):
    items = [measurement_data(r, "index_x") for r in simulated[:2]]
    res = fit_recordings(items, model="rich", timing="rig", progress=False)
    assert all(Status(int(s)) in (Status.CONVERGED, Status.ILL_CONDITIONED) for s in res.status)
    with pytest.raises(ValueError, match="relaxation2"):
        fit_recordings(items, model="rich", progress=False,
                         u0=np.stack([to_unconstrained(MeasurementModel("rich"), d.guess)
                                      for d in items]))


def test_a_measured_static_peak_rules_out_the_law_without_one(simulated):
    items = [measurement_data(r, "index_x") for r in simulated[:3]]
    models = [MeasurementModel("no_peak2"), MeasurementModel("relaxation2")]
    smaller, peak = (fit_recordings(items, model=m, progress=False) for m in models)
    z = (peak.values["f_static_excess"] / peak.stderr["f_static_excess"]).to_numpy()
    assert np.all(z > law_choice.PEAK_Z)  # every simulated material has a static peak
    cheaper = dataclasses.replace(smaller, bic=peak.bic - 100.0)  # the BIC prefers no peak
    _, chosen, table = law_choice.by_bic(models, [cheaper, peak])
    assert np.all(chosen == 1) and np.all(table.iloc[:, 0] < table.iloc[:, 1])
    faint = dataclasses.replace(peak, stderr=peak.stderr * 1e3)  # a peak within its noise
    _, chosen, _ = law_choice.by_bic(models, [cheaper, faint])
    assert np.all(chosen == 0)
    on_bound = dataclasses.replace(peak, stderr=peak.stderr * 0.0)  # no width: not measured
    _, chosen, _ = law_choice.by_bic(models, [cheaper, on_bound])
    assert np.all(chosen == 0)


def _fake_fits(ramps, sessions, channel="index_x"):
    """Items and a fit result of a batch with these fitted movement durations."""
    items = [dataclasses.make_dataclass("Item", ["session", "channel"])(s, channel)
             for s in sessions]
    values = pd.DataFrame({"ramp": ramps, "delay": 0.02, "accel": 0.1})
    fit = dataclasses.make_dataclass("Fit", ["u", "values"])([np.zeros(3)] * len(ramps), values)
    return items, fit


def test_a_profile_off_its_session_is_fitted_again_from_the_sessions():
    ramps = [0.100, 0.101, 0.099, 0.102, 0.100, 0.128, 0.098]
    items, fit = _fake_fits(ramps, [4] * 7)
    starts = measurement._rig_starts(items, fit)
    assert list(starts) == [5]
    assert starts[5] == {"delay": 0.02, "ramp": pytest.approx(0.100), "accel": 0.1}
    # a session whose recordings spread (the lab: robust sd ~12 %) has no outlier at +25 %
    rng = np.random.default_rng(0)
    spread = list(0.14 * np.exp(0.12 * rng.standard_normal(40))) + [0.14 * np.exp(0.25)]
    assert measurement._rig_starts(*_fake_fits(spread, [1] * 41)) == {}
    # too few fits of one session and channel, or no session: nothing to compare with
    assert measurement._rig_starts(*_fake_fits(ramps[3:], [4] * 4)) == {}
    assert measurement._rig_starts(*_fake_fits(ramps, [None] * 7)) == {}


def test_a_soft_material_trapped_by_a_slow_drive_is_freed_by_its_sessions_profile():
    # seed 1, session 4: bath-mat-2's fit can settle where a slower movement and a stiffer
    # contact fit nearly as well; with the fits whose movement is off their session's
    # fitted again from the session's profile, its k is within 5 % of the truth, its BIC
    # no higher than the single start's, and the other recordings' fits untouched
    labels = ["bath-mat-2", "paper-2", "pe-bag-2", "belt-2", "laundry-net-1", "curtain-rose-2"]
    recs = simulate_measurements([(4, label, 1) for label in labels], seed=1)
    items = [measurement_data(r, "index_x") for r in recs]
    kw = dict(model="relaxation2", progress=False)
    trapped = fit_recordings(items, refit_rig_outliers=False, **kw)
    res = fit_recordings(items, **kw)
    truth = measurement_truth(recs[0], "k")
    assert abs(res.values["k"][0] / truth - 1) < 0.05
    assert res.bic[0] <= trapped.bic[0]
    np.testing.assert_array_equal(res.bic[1:], trapped.bic[1:])  # the others as they were


def test_the_old_names_still_work_and_say_they_are_deprecated(simulated):
    items = [measurement_data(simulated[0], "index_x")]
    with pytest.warns(DeprecationWarning, match="fit_measurements is deprecated"):
        old = measurement.fit_measurements(items, model="no_peak2", progress=False)
    new = fit_recordings(items, model="no_peak2", progress=False)
    np.testing.assert_array_equal(np.stack(old.u), np.stack(new.u))
    with pytest.warns(DeprecationWarning, match="fit_motions is deprecated"):
        motions, item_of, _ = measurement.fit_motions(items, old)
    np.testing.assert_array_equal(item_of, new.per_motion().item_of)


def test_a_declared_stroke_puts_the_travel_in_mm_and_none_says_per_stroke(simulated):
    from frictionfit import Recording

    rec = simulated[1]
    declared = Recording.from_arrays(rec.samples, rec.sample_rate_hz, rec.channel_names,
                                     events=rec.events, name="declared",
                                     metadata={**rec.metadata, "stroke_mm": 13.0})
    bare = fit_recordings(rec, channels=["index_x"], model="relaxation2", progress=False)
    mm = fit_recordings(declared, channels=["index_x"], model="relaxation2", progress=False)
    per_stroke, per_mm = bare.to_frame(), mm.to_frame()
    assert "k [N/mm]" not in per_stroke and "slip_length [stroke]" in per_stroke
    # the same fit, its travel read in mm of the declared 13-mm stroke
    assert per_mm["k [N/mm]"][0] == pytest.approx(per_stroke["k [N/stroke]"][0] / 13.0)
    assert per_mm["slip_length [mm]"][0] == pytest.approx(
        per_stroke["slip_length [stroke]"][0] * 13.0)
    assert "N/mm" in mm.report(0) and "N/stroke" in bare.report(0)
    post = mm.posterior(method="laplace")
    assert post.quantiles[0]["k"][2] == pytest.approx(
        bare.posterior(method="laplace").quantiles[0]["k"][2] / 13.0, rel=1e-6)
    assert "k_median [N/mm]" in post.to_frame()


def test_noise_by_regime_splits_every_fitted_block_once():
    recs = simulate_measurements([(1, CLASSES[0], 1)], seed=0)
    res = fit_recordings(recs, channels=["index_x"], model="no_peak2", progress=False)
    table = res.noise_by_regime()
    assert list(table["regime"]) == ["moving", "holding"]
    assert table["blocks"].sum() == res.items[0].mask.sum()
    assert np.all(table["sd"] > 0) and np.all(np.abs(table["rho"]) < 1)
