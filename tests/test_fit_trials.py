"""Trials: the one batch type of per-motion fits, from arrays and from motions."""

import numpy as np
import pytest

from frictionfit.errors import FitError
from frictionfit.fit import FitResult, Trials, fit_trials
from frictionfit.recording import Event, Recording
from frictionfit.segmentation import segment
from frictionfit.simulation.trials import simulate_trials

EP = "elastic_plastic"


def test_a_fit_of_trials_equals_the_fit_of_their_arrays_bit_for_bit():
    ts = simulate_trials(EP, 3, seed=5)
    y = ts.y.copy()
    y[0, 300:700] = np.nan
    a = fit_trials(y, ts.t, (ts.t_out, ts.t_back), model=EP, chunk_size=4)
    trials = Trials.from_arrays(y, ts.t, (ts.t_out, ts.t_back))
    b = fit_trials(trials, model=EP, chunk_size=4)
    assert np.array_equal(np.stack(a.u), np.stack(b.u))
    assert np.array_equal(a.chi2, b.chi2) and np.array_equal(a.direction, trials.direction)
    np.testing.assert_array_equal(trials.mask, FitResult.sample_mask(y))


def test_a_given_displacement_is_carried_and_arrays_are_not_given_twice():
    ts = simulate_trials(EP, 2, seed=1)
    x = np.clip((ts.t - ts.t_out) / 0.12, 0.0, 1.0)
    trials = Trials.from_arrays(ts.y, ts.t, x[None].repeat(2, 0), drive="given")
    assert trials.drive == "given" and trials.drive_input.shape == ts.y.shape
    a = fit_trials(ts.y, ts.t, x[None].repeat(2, 0), drive="given", model=EP)
    assert np.array_equal(np.stack(fit_trials(trials, model=EP).u), np.stack(a.u))
    with pytest.raises(FitError, match="Trials bring their own t, direction"):
        fit_trials(trials, ts.t, direction=ts.direction)
    with pytest.raises(FitError, match="y has 2000 samples per trial but t has 4"):
        Trials.from_arrays(ts.y, ts.t[:4], (0.0, 0.002))
    with pytest.raises(FitError, match="drive must be 'events' or 'given', not 'measurement'"):
        fit_trials(ts.y, ts.t, (0.05, 1.05), drive="measurement")


def test_take_keeps_every_per_trial_field_in_order():
    ts = simulate_trials(EP, 3, seed=2)
    trials = Trials.from_arrays(ts.y, ts.t, (ts.t_out, [1.0, 1.05, 1.1]), ids=["a", "b", "c"])
    part = trials.take([2, 0])
    assert part.ids == ("c", "a") and part.n_trials == 2
    np.testing.assert_array_equal(part.y, ts.y[[2, 0]])
    np.testing.assert_array_equal(part.drive_input[1], [1.1, 1.0])
    np.testing.assert_array_equal(part.direction, trials.direction[[2, 0]])


def test_from_motions_makes_one_trial_per_motion_and_channel_on_the_first_grid():
    ts = simulate_trials(EP, 2, seed=4, snr_db=30)
    samples = np.concatenate([ts.y.T, ts.y.T])
    events = [Event(ts.t_out + 2 * k + dt, "move", tgt)
              for k in range(2) for dt, tgt in ((0.0, "p2"), (1.0, "p1"))]
    rec = Recording.from_arrays(samples, 1000.0, ["index_x", "thumb_x"], events=events,
                                name="m1")
    motions = segment(rec)
    trials = Trials.from_motions(motions)
    assert trials.n_trials == 2 * len(motions)
    assert trials.ids[:2] == (f"m1/motion{motions[0].index}/index_x",
                              f"m1/motion{motions[0].index}/thumb_x")
    assert trials.groups[0] == trials.groups[1] == f"m1/motion{motions[0].index}"
    np.testing.assert_array_equal(trials.t, motions[0].t)
    last = motions[-1]
    n = min(trials.t.size, last.t.size)
    np.testing.assert_array_equal(trials.y[-1, :n], last.samples[:n, 1])
    assert np.isnan(trials.y[-1, n:]).all()
    np.testing.assert_array_equal(trials.drive_input[0][-1], last.t_out)
    thumb = Trials.from_motions(motions, channels=["thumb_x"])
    np.testing.assert_array_equal(thumb.y, trials.y[1::2])
    assert thumb.ids == trials.ids[1::2]
    with pytest.raises(FitError, match="has no channel 'wrist_x'"):
        Trials.from_motions(motions, channels=["wrist_x"])
    with pytest.raises(FitError, match="no motions"):
        Trials.from_motions([])
