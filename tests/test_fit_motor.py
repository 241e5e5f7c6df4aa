"""The motor's own movements from its position reads, and the whole fits driven by them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import frictionfit.fit._timing as timing
from frictionfit.acquisition.actuator import SimulatedGripper
from frictionfit.cli import app
from frictionfit.errors import Status
from frictionfit.features._base import content_key
from frictionfit.fit import measurement_data
from frictionfit.fit.measurement_data import _move_signs
from frictionfit.fit.motor import motor_timing
from frictionfit.recording import MOTOR_POSITIONS, read_recording, write_recording
from frictionfit.simulation.measurements import measurement_truth, simulate_measurements
from frictionfit.whole_fit import fit_recordings

SPECS = [(1, "carpet-1", 1), (2, "paper-2", 1), (1, "cushion-1", 2)]


@pytest.fixture(scope="module")
def read():
    return simulate_measurements(SPECS, seed=7, position_rate_hz=50.0)


def _true_moves(rec):
    moves = [(m["move_out"], m["move_back"]) for m in rec.truth["motions"]]
    onset = np.array([a[0] for pair in moves for a in pair])
    stop = np.array([a[1] for pair in moves for a in pair])
    return onset, stop - onset


def test_reads_do_not_change_the_forces(read):
    plain = simulate_measurements(SPECS, seed=7)
    for a, b in zip(plain, read, strict=True):
        np.testing.assert_array_equal(a.samples, b.samples)
        assert a.motor_positions() is None and b.motor_positions() is not None


def test_each_movement_timed_from_reads_at_50_hz(read, tmp_path):
    for rec in read:
        rec = read_recording(write_recording(rec, tmp_path / rec.name))  # as written
        timing = motor_timing(rec, *_move_signs(rec))
        onset, duration = _true_moves(rec)
        assert timing.seen.all() and timing.n_reads == 502
        # reads 20 ms apart, times known to ~1 ms: onsets to 2 ms, durations to 3 %
        np.testing.assert_allclose(timing.onset, onset, atol=2e-3)
        np.testing.assert_allclose(timing.duration, duration, rtol=0.03)
        true_accel = rec.truth["session"]["accel_s"] / np.median(duration)
        assert timing.accel == pytest.approx(true_accel, abs=0.03)
        assert timing.rms_counts < 1.0  # whole counts: the profile fits to their rounding


def test_reads_of_any_rate_are_used():
    rec, = simulate_measurements([(1, "floor-mat-1", 1)], seed=7, position_rate_hz=200.0)
    timing = motor_timing(rec, *_move_signs(rec))  # 2010 reads: two compiled chunks
    onset, duration = _true_moves(rec)
    assert timing.n_reads == 2010 and timing.seen.all()
    np.testing.assert_allclose(timing.onset, onset, atol=1e-3)
    np.testing.assert_allclose(timing.duration, duration, rtol=0.01)


def _with_reads(rec, position):
    """``rec`` with its reads' positions replaced by ``position(t)`` at their times."""
    block = rec.extra[MOTOR_POSITIONS]
    reads = np.array(block["reads"])
    reads[:, 2] = np.round(position(reads[:, :2].mean(axis=1)))
    return dataclasses.replace(rec, extra={MOTOR_POSITIONS: dict(block, reads=reads.tolist())})


def test_a_raised_cosine_motor_is_timed_too(read):
    # the acquisition's simulated gripper moves on a raised cosine, not a trapezoid
    rec = read[1]
    commands, signs = _move_signs(rec)
    gripper = SimulatedGripper(2048.0, move_s=0.12, latency_s=0.02,
                               clock=iter([0.0, *commands]).__next__)
    for sign in signs:
        gripper.move_to(2304.0 if sign > 0 else 2048.0)
    timing = motor_timing(_with_reads(rec, gripper.trajectory), commands, signs)
    assert timing.seen.all()
    np.testing.assert_allclose(timing.onset, commands + 0.02, atol=3e-3)
    np.testing.assert_allclose(timing.duration, 0.12, rtol=0.05)


def test_reads_that_show_no_movement_are_not_used(read):
    rec = read[0]
    commands, signs = _move_signs(rec)
    # a drive that jumps between reads: no read inside any movement
    jumps = _with_reads(rec, lambda t: 2048.0 + 256.0 * (np.searchsorted(commands, t) % 2))
    timing = motor_timing(jumps, commands, signs)
    assert timing is None or not timing.seen.any()
    assert measurement_data(jumps, "index_x").motor is None
    noisy = _with_reads(rec, lambda t: 2048.0 + 100.0 * np.sin(40.0 * t))  # not a trapezoid
    assert motor_timing(noisy, commands, signs) is None


def test_reads_are_part_of_a_recordings_cache_key(read):
    # cached feature rows of the fitted sets depend on the reads
    plain = dataclasses.replace(read[0], extra={})
    assert content_key(plain) != content_key(read[0])
    assert content_key(plain) == content_key(dataclasses.replace(read[0], extra={}))


def test_malformed_reads_are_named_and_the_forces_still_fitted(read):
    bad = dataclasses.replace(read[0], extra={MOTOR_POSITIONS: {"columns": [{"name": "t"}],
                                                                "reads": [[0.1]]}})
    with pytest.warns(UserWarning, match="s1_carpet-1_01.*malformed 'motor_positions'.*force"):
        d = measurement_data(bad, "index_x")
    assert d.motor is None and d.y.size > 1000
    assert content_key(bad) != content_key(read[0])


def test_a_recordings_channels_share_one_timing(read):
    commands, signs = _move_signs(read[0])
    assert motor_timing(read[0], commands, signs) is motor_timing(read[0], commands, signs)
    assert (measurement_data(read[0], "thumb_x").motor
            is measurement_data(read[0], "index_x").motor)


def test_too_few_reads_leave_the_timing_to_the_force(read):
    rec = read[0]
    block = dict(rec.extra[MOTOR_POSITIONS], reads=rec.extra[MOTOR_POSITIONS]["reads"][:30])
    sparse = dataclasses.replace(rec, extra={MOTOR_POSITIONS: block})
    assert motor_timing(sparse, *_move_signs(sparse)) is None
    assert measurement_data(sparse, "index_x").motor is None
    assert motor_timing(dataclasses.replace(rec, extra={}), *_move_signs(rec)) is None


def test_the_whole_fit_takes_each_movements_timing_from_the_motor(read, monkeypatch):
    items = [measurement_data(rec, "index_x") for rec in read]
    for d, rec in zip(items, read, strict=True):
        onset, duration = _true_moves(rec)
        # the drive starts each movement at its command + delay and runs ramp x stretch
        np.testing.assert_allclose(d.commands + d.guess["delay"], onset, atol=2e-3)
        np.testing.assert_allclose(d.stretch * d.guess["ramp"], duration, rtol=0.03)

    def not_searched(*args, **kwargs):
        raise AssertionError("the force was searched for a timing the motor reported")

    monkeypatch.setattr(timing, "_movement_timing", not_searched)
    res = fit_recordings(items, progress=False)
    for i, (rec, status) in enumerate(zip(read, res.status, strict=True)):
        v, se = res.params(i), res.stderrs(i)
        assert status == Status.CONVERGED
        truth = {n: measurement_truth(rec, n) for n in ("k", "f_kin")}
        # the stiff paper's k is the hard one: 23.0 +- 1.9 N/mm for 26.2
        assert abs(v["k"] - truth["k"]) < 3 * se["k"] and v["k"] == pytest.approx(truth["k"],
                                                                                  rel=0.15)
        assert v["f_kin"] == pytest.approx(truth["f_kin"], rel=0.05)
    for d, fitted in zip(items, res.items, strict=True):  # the motor's timing kept
        np.testing.assert_array_equal(fitted.commands, d.commands)
        np.testing.assert_array_equal(fitted.stretch, d.stretch)


def test_cli_simulates_the_motors_reads(tmp_path):
    out = tmp_path / "sim"
    result = CliRunner().invoke(app, ["simulate", "--out", str(out), "--classes", "paper-2",
                                      "--sessions", "1", "--measurements-per-class", "1",
                                      "--motor-positions", "50", "--no-progress"])
    assert result.exit_code == 0, result.output
    rec = read_recording(out / "s1_paper-2_01")
    assert measurement_data(rec, "index_x").motor.seen.all()
    write_recording(dataclasses.replace(rec, extra={}, name="s1_paper-2_02"),
                    out / "s1_paper-2_02")  # the same without its reads
    result = CliRunner().invoke(app, ["fit", str(out), "--channel", "index_x", "--out",
                                      str(tmp_path / "fits.csv")])
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "fits.csv")
    assert dict(zip(table["trial"], table["timing"], strict=True)) == {
        "s1_paper-2_01/index_x": "motor", "s1_paper-2_02/index_x": "force"}
