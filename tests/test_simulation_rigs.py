"""Simulated rigs: the default is the simulator without rigs; each effect does what it says."""

import dataclasses

import numpy as np
import pytest
from typer.testing import CliRunner

from frictionfit.cli import app
from frictionfit.recording import read_dataset
from frictionfit.simulation.measurements import simulate_measurements
from frictionfit.simulation.rigs import DEFAULT, RIGS, SimulatedRig, rig_for

SPECS = [(1, "paper-2", 1), (2, "carpet-1", 2)]


def _index_x(rec):
    return rec.samples[:, rec.channel_names.index("index_x")]


def test_the_default_rig_is_the_simulator_without_rigs():
    plain = simulate_measurements(SPECS, seed=3)
    rigged = simulate_measurements(SPECS, seed=3, rig=SimulatedRig())
    for a, b in zip(plain, rigged, strict=True):
        np.testing.assert_array_equal(a.samples, b.samples)
        assert a.metadata == b.metadata and "stroke_mm" not in a.metadata
        assert a.truth == b.truth


def test_a_rig_declares_its_name_stroke_and_rate():
    rec, = simulate_measurements(SPECS[:1], seed=3, rig=RIGS["sim-b"])
    assert rec.metadata["rig"] == "sim-b" and rec.stroke_mm == 0.9
    assert rec.sample_rate_hz == 500.0 and np.median(np.diff(rec.t)) == pytest.approx(0.002)
    assert rec.truth["rig"]["finger_k"] == 150.0


def test_a_compliant_finger_lowers_the_loading_slope_by_the_series_stiffness():
    stiff = dataclasses.replace(DEFAULT, name="stiff", finger_k=None)
    # paper-2: k about 24.5 N/mm; a 24.5 N/mm finger halves the series stiffness
    soft = dataclasses.replace(DEFAULT, name="soft", finger_k=24.5)
    a, = simulate_measurements(SPECS[:1], seed=3, rig=stiff)
    b, = simulate_measurements(SPECS[:1], seed=3, rig=soft)
    window = (a.t > 2.06) & (a.t < 2.08)  # the loading of the second out stroke
    slope_a = np.nanmax(np.abs(np.gradient(_index_x(a)[window])))
    slope_b = np.nanmax(np.abs(np.gradient(_index_x(b)[window])))
    assert 0.3 < slope_b / slope_a < 0.8  # a half, blurred by noise and the motor's ramp
    assert a.truth["motions"][1]["params"]["k"] == b.truth["motions"][1]["params"]["k"]


def test_play_delays_the_finger_after_each_reversal():
    loose = dataclasses.replace(DEFAULT, name="loose", play_mm=0.3)
    a, = simulate_measurements(SPECS[:1], seed=3)
    b, = simulate_measurements(SPECS[:1], seed=3, rig=loose)
    after = (a.t > 3.05) & (a.t < 3.09)  # the motor half way back: the finger not yet moved
    assert np.nanstd(_index_x(b)[after]) < 0.5 * np.nanstd(_index_x(a)[after])


def test_creep_relaxes_the_held_force():
    creeping = dataclasses.replace(DEFAULT, name="creeping", creep_mm_per_n=0.02,
                                   creep_tau_s=0.3)
    a, = simulate_measurements(SPECS[:1], seed=3)
    b, = simulate_measurements(SPECS[:1], seed=3, rig=creeping)

    def relaxed(rec):
        x = _index_x(rec)
        early, late = (rec.t > 2.25) & (rec.t < 2.3), (rec.t > 2.9) & (rec.t < 2.95)
        return abs(np.nanmean(x[early]) - np.nanmean(x[late]))

    assert relaxed(b) > relaxed(a) + 0.005


@pytest.mark.parametrize("kwargs, match", [
    (dict(rate_hz=300.0), "rate_hz must divide 1000 Hz"),
    (dict(motor_speed=0.0), "motor_speed must be > 0"),
    (dict(stroke_mm=-1.0), "stroke_mm must be > 0 or None"),
    (dict(play_mm=-0.1), "play_mm and creep_mm_per_n must be >= 0"),
])
def test_bad_rigs_are_refused_by_name(kwargs, match):
    with pytest.raises(ValueError, match=f"rig 'x': {match}"):
        SimulatedRig("x", **kwargs)
    with pytest.raises(ValueError, match="unknown simulated rig 'lab-z'; choose from"):
        rig_for("lab-z")


def test_simulate_writes_a_rigs_measurements(tmp_path):
    runner = CliRunner()
    result = runner.invoke(app, ["simulate", "--out", str(tmp_path), "--sessions", "1",
                                 "--measurements-per-class", "1", "--classes", "paper-1",
                                 "--rig", "sim-c", "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "wrote 1 measurements (1 classes, 1 session(s), rig sim-c)" in result.output
    rec, = read_dataset(tmp_path)
    assert rec.rig.name == "sim-c" and rec.stroke_mm == 1.6
    bad = runner.invoke(app, ["simulate", "--out", str(tmp_path / "b"), "--rig", "lab-z"])
    assert bad.exit_code == 2 and "unknown rig 'lab-z'" in bad.output
