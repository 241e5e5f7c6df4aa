"""Quantities derived from whole-measurement fits: the held and peak forces, the stick-slip."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from frictionfit.fit import measurement_data
from frictionfit.fit.derived import ONSET_SAMPLES, SLIP_S, _band_rms
from frictionfit.simulation.measurements import simulate_measurements
from frictionfit.whole_fit import fit_recordings

CHANNEL = "index_x"


@pytest.fixture(scope="module")
def recordings():
    return simulate_measurements([(1, "carpet-1", 1), (1, "paper-2", 1), (2, "cushion-1", 1)],
                                 seed=11)


def _with_shaking(rec, amplitude: float, hz: float = 70.0):
    """``rec`` with a sine of ``amplitude`` (N) on CHANNEL for SLIP_S after every command."""
    samples = np.array(rec.samples, dtype=np.float64)
    j = rec.channel_names.index(CHANNEL)
    for e in rec.events:
        if e.kind == "move":
            window = (rec.t >= e.t) & (rec.t < e.t + SLIP_S)
            samples[window, j] += amplitude * np.sin(2 * np.pi * hz * (rec.t[window] - e.t))
    return dataclasses.replace(rec, samples=samples)


def test_held_force_is_the_step_between_the_data_held_levels(recordings):
    items = [measurement_data(r, CHANNEL) for r in recordings]
    res = fit_recordings(items, model="relaxation2", progress=False)
    for d, values, derived in zip(items, res.values.to_dict("records"), res.derived,
                                  strict=True):
        held, se = derived["f_held"]
        ends = []  # the data's level over the last 50 ms of every fitted hold, drift removed
        for c in d.commands[3:]:
            last = d.mask & (d.t > c - 0.05) & (d.t < c)
            ends.append(np.mean(d.y[last] - values["drift"] * d.t[last]))
        steps = 0.5 * np.abs(np.diff(ends))
        assert held == pytest.approx(np.median(steps), rel=0.05)
        assert 0 < se < 0.05 * held


def test_peak_force_is_half_the_data_swing_between_strokes(recordings):
    items = [measurement_data(r, CHANNEL) for r in recordings]
    res = fit_recordings(items, model="relaxation2", progress=False)
    for d, values, derived in zip(items, res.values.to_dict("records"), res.derived,
                                  strict=True):
        peak, se = derived["f_peak"]
        swings = []  # per fitted out-back pair: half the data's peak-to-peak, drift removed
        y = d.direction * (d.y - values["drift"] * d.t)
        for c_out, c_back, c_next in zip(d.commands[2::2], d.commands[3::2], d.commands[4::2],
                                         strict=False):
            out = d.mask & (d.t >= c_out) & (d.t < c_back)
            back = d.mask & (d.t >= c_back) & (d.t < c_next)
            swings.append(0.5 * (y[out].max() - y[back].min()))
        assert peak == pytest.approx(np.median(swings), rel=0.1)
        assert peak > derived["f_held"][0] and 0 < se < 0.05 * peak


def test_onset_rate_is_the_data_steepest_rise_in_out_strokes(recordings):
    items = [measurement_data(r, CHANNEL) for r in recordings]
    res = fit_recordings(items, model="relaxation2", progress=False)
    for d, derived in zip(items, res.derived, strict=True):
        rate, se = derived["onset_rate"]
        y, n = d.direction * d.y, ONSET_SAMPLES  # the grid is 1 ms while the finger moves
        steepest = []
        for c_out in d.commands[2::2]:
            window = np.flatnonzero(d.mask & (d.t >= c_out) & (d.t < c_out + 0.2))
            steepest.append(np.max(y[window[n:]] - y[window[:-n]]) / (n * 1e-3))
        assert rate == pytest.approx(np.median(steepest), rel=0.15)
        assert 0 < se < 0.1 * rate
    frame = res.to_frame()  # the table's headers carry each quantity's own unit
    assert {"onset_rate [N/s]", "onset_rate_stderr [N/s]", "f_held [N]"} <= set(frame.columns)
    assert frame["onset_rate [N/s]"].tolist() == [d["onset_rate"][0] for d in res.derived]


def test_static_level_carries_the_covariance_of_its_two_parts(recordings):
    items = [measurement_data(r, CHANNEL) for r in recordings]
    res = fit_recordings(items, model="relaxation2", progress=False)
    for i in range(res.n_trials):
        v, (static, se) = res.params(i), res.derived[i]["f_static"]
        assert static == pytest.approx(v["f_kin"] + v["f_static_excess"], rel=1e-12)
        model, names = res.member(i), res.free_names(i)
        u = np.asarray(res.u[i], dtype=np.float64)

        def total(w, model=model):
            p = model.physical(w)
            return float(p["f_kin"] + p["f_static_excess"])

        grad = []  # central differences in the unconstrained coordinates of the free ones
        for name in names:
            j, h = model.param_names.index(name), 1e-6
            grad.append((total(u + h * np.eye(u.size)[j]) - total(u - h * np.eye(u.size)[j]))
                        / (2 * h))
        grad = np.asarray(grad)
        assert se == pytest.approx(np.sqrt(grad @ res.cov[i] @ grad), rel=1e-4)
        assert se < np.hypot(res.stderr["f_kin"][i], res.stderr["f_static_excess"][i])


def test_joint_covariance_of_parameters_and_derived_quantities(recordings):
    """``quantity_cov``: its diagonal is the reported stderrs squared, and ``f_static``
    covaries as the sum of its two parts does (each from its own gradient)."""
    items = [measurement_data(r, CHANNEL) for r in recordings]
    res = fit_recordings(items, model="relaxation2", progress=False)
    names = ["k", "f_kin", "f_static_excess", "f_static", "f_held", "slip_noise", "leak"]
    for i in range(res.n_trials):
        cov = res.quantity_cov(i, names)
        se = {**res.stderrs(i), **{n: s for n, (_, s) in res.derived[i].items()}}
        np.testing.assert_allclose(np.sqrt(np.diag(cov)), [se[n] for n in names], rtol=1e-6)
        parts = cov[1] + cov[2]  # cov(f_kin + f_static_excess, each quantity)
        np.testing.assert_allclose(cov[3], parts, rtol=1e-4, atol=1e-9 * np.abs(cov).max())
        assert np.all(cov[5, :5] == 0) and cov[5, 5] > 0
        assert np.all(np.linalg.eigvalsh(cov) > -1e-12 * np.abs(cov).max())
    with pytest.raises(KeyError, match="neither a parameter"):
        res.quantity_cov(0, ["k", "nonsense"])


def test_slip_noise_measures_shaking_the_smooth_law_cannot_follow(recordings):
    t = np.arange(0.0, SLIP_S, 1e-3)
    amplitude = 0.1  # N
    expected = _band_rms(amplitude * np.sin(2 * np.pi * 70.0 * t))
    clean = [measurement_data(r, CHANNEL) for r in recordings]
    shaken = [measurement_data(_with_shaking(r, amplitude), CHANNEL) for r in recordings]
    res = fit_recordings(clean + shaken, model="relaxation2", progress=False)
    slip = np.array([d["slip_noise"][0] for d in res.derived])
    n = len(recordings)
    assert np.all(slip[:n] < 0.3 * expected)  # the simulator's law has no stick-slip
    np.testing.assert_allclose(slip[n:], expected, rtol=0.3)
    se = np.array([d["slip_noise"][1] for d in res.derived])
    assert np.all(np.isfinite(se)) and np.all(se < slip[n:].max())


def test_slip_noise_is_nan_without_sample_by_sample_movements(recordings):
    d = measurement_data(recordings[0], CHANNEL, decimate=2)
    res = fit_recordings([d], model="relaxation2", progress=False, max_steps=30)
    assert np.isnan(res.derived[0]["slip_noise"][0])
    assert np.isfinite(res.derived[0]["f_held"][0])
