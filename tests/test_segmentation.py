"""Segmentation: motion windows, NaN for dropped samples, boundaries found in the force."""

from dataclasses import replace

import numpy as np
import pytest

from frictionfit.errors import RecordingError
from frictionfit.recording import Event, Recording
from frictionfit.segmentation import (
    moving_average,
    regrid,
    robust_sd,
    segment,
    suspect_samples,
)


def _measurement(n_motions=3, rate=1000.0):
    n = int(2 * n_motions * rate)
    samples = np.arange(n, dtype=float)[:, None] * [1.0, -1.0]
    events = [Event(0.05 + 2 * k + dt, "move", tgt)
              for k in range(n_motions) for dt, tgt in ((0.0, "p2"), (1.0, "p1"))]
    return Recording.from_arrays(samples, rate, ["index_x", "thumb_x"], events=events,
                                 metadata={"label": "paper-1"})


def test_motions_start_pre_s_before_each_out_command():
    motions = segment(_measurement())
    assert [m.index for m in motions] == [1, 2]  # motion 0 (preparatory) dropped
    m = motions[0]
    assert m.t_out == pytest.approx(0.05) and m.t_back == pytest.approx(1.05)
    assert m.samples[0, 0] == 2000.0 and m.samples.shape == (2000, 2)
    assert [p.kind for p in m.phases] == ["move_out", "relax_out", "move_back", "relax_back"]
    assert m.metadata == {"label": "paper-1", "motion": 1}


def test_dropped_samples_become_nan_on_the_grid():
    rec = _measurement()
    keep = np.r_[0:2500, 2600:rec.n_samples]
    rec = Recording(rec.t[keep], rec.samples[keep], 1000.0, rec.channels, rec.events)
    t, grid = regrid(rec)
    assert grid.shape[0] == 6000 and np.isnan(grid[2500:2600]).all()
    m = segment(rec)[0]
    assert np.isnan(m.samples[500:600, 0]).all()
    assert np.isfinite(m.samples[:500]).all() and np.isfinite(m.samples[600:]).all()


def test_moving_average_ignores_nan():
    x = np.array([1.0, 2.0, np.nan, 4.0, 5.0])
    np.testing.assert_allclose(moving_average(x, 3), [1.5, 1.5, 3.0, 4.5, 4.5])


def test_robust_sd_is_scipys_normal_scaled_median_absolute_deviation():
    from scipy.stats import median_abs_deviation

    x = np.random.default_rng(3).standard_t(3, size=(101, 4))
    assert robust_sd(x[:, 0]) == median_abs_deviation(x[:, 0], scale="normal")
    assert np.array_equal(robust_sd(x, axis=0), median_abs_deviation(x, axis=0, scale="normal"))
    about_zero = median_abs_deviation(x[:, 1], center=lambda a, axis: 0.0, scale="normal")
    assert robust_sd(x[:, 1], centre=0.0) == about_zero != robust_sd(x[:, 1])
    assert np.isnan(robust_sd(np.array([1.0, np.nan, 2.0])))


def test_moving_average_of_a_signal_shorter_than_its_window_keeps_the_length():
    np.testing.assert_allclose(moving_average(np.array([1.0, 2.0, 6.0]), 25), [1.5, 3.0, 4.0])
    assert moving_average(np.array([]), 25).shape == (0,)


def test_no_events_is_a_named_error():
    rec = Recording.from_arrays(np.zeros((100, 1)), 1000.0, ["x"],
                                name="s1_x_01")
    with pytest.raises(RecordingError, match="s1_x_01: no 'move p2' events and no movements"):
        segment(rec)


# Boundaries against the simulator's motor profile. Hard cases: soft materials whose
# relaxation and slip-weakening hide the stop, stiff ones with a sharp peak, a long
# (15 ms) deceleration in session 2 of seed 1, and faults.
SPECS = [(2, "bath-mat-1", 2), (2, "curtain-rose-1", 1), (1, "cushion-1", 1),
         (1, "aluminium-foil-1", 1), (2, "carpet-1", 1), (1, "paper-2", 2)]


@pytest.fixture(scope="module")
def simulated():
    from frictionfit.simulation.measurements import simulate_measurements

    return simulate_measurements(SPECS, seed=1, pad_to=len(SPECS))


def _errors_ms(rec, motions):
    """Per fault-free motion: detected minus true boundaries (ms), matched by motion index."""
    faulty = {f["motion"] for f in rec.truth["faults"]}
    out = {}
    for m in motions:
        if m.index in faulty:
            continue
        tm = rec.truth["motions"][m.index]
        found = [m.t0 + m.phases[0].start_s, m.t0 + m.phases[0].stop_s,
                 m.t0 + m.phases[2].start_s, m.t0 + m.phases[2].stop_s]
        out[m.index] = 1e3 * (np.array(found) - [*tm["move_out"], *tm["move_back"]])
    return out


@pytest.mark.parametrize("use_events", [True, False])
def test_boundaries_within_5_ms_of_the_motor(simulated, use_events):
    n = 0
    for rec in simulated:
        given = rec if use_events else replace(rec, events=())
        motions = segment(given)
        assert [m.index for m in motions] == [1, 2, 3, 4], rec.name
        assert all(mv.detected for m in motions for mv in m.movements)
        for index, err in _errors_ms(rec, motions).items():
            assert np.abs(err).max() < 5.0, (rec.name, index, err)
            n += 1
    assert n >= 15  # most motions are fault-free (17 of 24 here)


def test_without_events_the_commands_are_estimated(simulated):
    rec = simulated[0]
    with_events = segment(rec)
    without = segment(replace(rec, events=()), lag_s=0.025)
    for a, b in zip(with_events, without, strict=True):
        assert b.t0 + b.t_out == pytest.approx(a.t0 + a.t_out, abs=0.015)  # latency 15-35 ms
        assert b.samples.shape == a.samples.shape


def test_a_fault_over_a_boundary_does_not_sink_the_measurement(simulated):
    rec = simulated[3]
    t, grid = regrid(rec)
    grid[2070:2200] = np.nan  # the whole out movement of motion 1 is lost
    keep = np.isfinite(grid[:, 0])
    broken = Recording(t[keep], grid[keep], rec.sample_rate_hz, rec.channels, rec.events,
                       rec.metadata, rec.truth, rec.name)
    motions = segment(broken)
    assert [m.index for m in motions] == [1, 2, 3, 4]
    errors = _errors_ms(rec, motions)
    assert all(np.abs(e).max() < 5.0 for i, e in errors.items() if i != 1)


def test_spikes_and_stuck_values_are_masked_and_reported(simulated):
    rec = simulated[3]
    samples = rec.samples.copy()
    samples[2500, 1] += 25.0  # a spike on thumb_y in motion 1
    samples[4300:4400] = samples[4299]  # the link repeats one row for 100 ms in motion 2
    broken = replace(rec, samples=samples)
    motions = {m.index: m for m in segment(broken)}
    one, two = motions[1], motions[2]
    assert "1 spike(s) masked" in one.problems
    # motion k starts at 2k s (50 ms before its out command): sample 2500 is row 500 of motion 1
    assert np.isnan(one.samples[500, 1]) and np.isfinite(one.samples[500, 0])
    assert "100 stuck sample(s) masked" in two.problems  # row 4299 itself is genuine
    assert np.isnan(two.samples[300:400]).all() and np.isfinite(two.samples[299]).all()
    kept = {m.index: m for m in segment(broken, mask_faults=False)}
    assert kept[1].samples[500, 1] == samples[2500, 1] and kept[1].problems == one.problems
    faulty = {f["motion"] for f in rec.truth["faults"]}  # here NaN bursts and spikes
    assert all(bool(m.problems) == (m.index in faulty) for m in segment(rec))


def test_samples_the_daq_flagged_overloaded_are_masked_and_reported(simulated):
    rec = simulated[3]
    runs = [{"channel": "index_x", "t": 4.3, "samples": 100}]
    flagged = replace(rec, extra={**rec.extra, "acquisition": {"overloads": runs}})
    j = rec.channel_names.index("index_x")
    two = {m.index: m for m in segment(flagged)}[2]
    # motion 2 starts at 4 s: t = 4.3 s is its row 300
    assert "100 sample(s) the DAQ flagged overloaded masked" in two.problems
    assert np.isnan(two.samples[300:400, j]).all()
    assert np.isfinite(two.samples[[299, 400], j]).all()
    assert np.isfinite(np.delete(two.samples[300:400], j, axis=1)).all()
    kept = {m.index: m for m in segment(flagged, mask_faults=False)}[2]
    assert np.isfinite(kept.samples[300:400, j]).all() and kept.problems == two.problems


def test_noise_free_plateaus_are_not_called_stuck():
    x = np.repeat([0.0, 1.0, 0.5, 0.2], 50)[:, None] * [1.0, -1.0]  # exact repeats everywhere
    spike, stuck = suspect_samples(x)
    assert not stuck.any() and not spike.any()
    noisy = np.random.default_rng(0).normal(0, 0.003, (400, 2))
    noisy[100:130] = noisy[99]
    assert suspect_samples(noisy)[1].sum() == 30


def test_faults_are_looked_for_once_per_recording_and_shared_read_only():
    from frictionfit.segmentation import checked_grid

    rec = _measurement()
    rec.samples[3000, 0] = 1e4  # a spike
    first, again = checked_grid(rec), checked_grid(rec)
    assert first.spike is again.spike and first.spike[3000, 0] and first.spike.sum() == 1
    assert not first.spike.flags.writeable and not first.stuck.flags.writeable
    assert first.samples is not again.samples  # each caller owns its grid
    np.testing.assert_array_equal(first.samples, regrid(rec)[1])


def test_change_point_choice_equals_the_full_least_squares_fit():
    """Projecting the common columns out picks the design a full weighted least-squares
    fit of each candidate picks (random designs, no near-ties)."""
    from frictionfit.segmentation import _best

    rng = np.random.default_rng(3)
    for _ in range(20):
        n, q, m, g = 60, 3, int(rng.integers(1, 4)), 40
        common = rng.normal(size=(n, q))
        varying = rng.normal(size=(g, n, m))
        w = rng.uniform(0.0, 1.0, n) * (rng.random(n) > 0.1)
        y = common @ rng.normal(size=q) + varying[7] @ rng.normal(size=m) + 0.1 * rng.normal(size=n)
        rss = []
        for k in range(g):
            x = np.hstack([common, varying[k]]) * np.sqrt(w)[:, None]
            coef = np.linalg.lstsq(x, y * np.sqrt(w), rcond=None)[0]
            rss.append(np.sum((x @ coef - y * np.sqrt(w)) ** 2))
        assert _best(y, w, common, varying) == int(np.argmin(rss))
