"""Simulated rubbing measurements: library, lab layout, truth, faults, round trip, determinism."""

import copy
import dataclasses
import json

import numpy as np
import pytest

from frictionfit.recording import read_dataset, read_recording, write_recording
from frictionfit.simulation.materials import CLASSES, MATERIALS, material_for
from frictionfit.simulation.measurements import (
    CHANNELS,
    N_SAMPLES,
    measurement_truth,
    simulate_dataset,
    simulate_measurements,
)

#: One compiled batch shape for the whole file (padding does not change the data).
PAD = 8
SPECS = [(1, "paper-1", 1), (1, "paper-2", 1), (2, "cushion-1", 1), (2, "pe-bag-2", 2),
         (1, "floor-mat-1", 3), (2, "curtain-rose-2", 1), (1, "banknote-1", 2),
         (2, "aluminium-foil-2", 4)]


@pytest.fixture(scope="module")
def recs():
    return simulate_measurements(SPECS, seed=5, pad_to=PAD)


def test_library_has_35_classes_with_two_layers_sliding_easier():
    assert len(CLASSES) == 35 and "cushion-2" not in CLASSES
    one, two = material_for("paper-1"), material_for("paper-2")
    assert two.f_kin < one.f_kin and two.k < one.k and two.tau > one.tau
    close = MATERIALS["curtain-rose-1"], MATERIALS["curtain-white-1"]
    assert abs(close[0].f_kin - close[1].f_kin) < 0.05 * close[0].f_kin
    with pytest.raises(ValueError, match="unknown class 'silk-1'"):
        material_for("silk-1")


def test_layout_matches_the_lab(recs):
    rec = recs[0]
    assert rec.name == "s1_paper-1_01" and rec.channel_names == CHANNELS
    assert rec.metadata == {"label": "paper-1", "material": "paper", "layers": 1, "session": 1,
                            "trial": 1, "rig": "frictionfit-simulator", "synthetic": True}
    assert [(e.t, e.target) for e in rec.events[:4]] == [
        (0.05, "p2"), (1.05, "p1"), (2.05, "p2"), (3.05, "p1")]
    clean = [r for r in recs if not r.truth["faults"]][0]
    assert clean.n_samples == N_SAMPLES and clean.duration_s == pytest.approx(10.049)
    # thumb sees roughly the opposite of the index finger
    x = clean.samples - np.median(clean.samples, axis=0)
    assert np.corrcoef(x[:, 0], x[:, 2])[0, 1] < -0.9
    # forces are whole millinewtons (ADC quantisation, 3 decimals in the CSV)
    assert np.allclose(clean.samples * 1000, np.round(clean.samples * 1000), atol=1e-6)


def test_force_carries_on_through_the_holds_between_motions(recs):
    # one continuous history: no step where one motion's window meets the next (in the
    # holds at 2, 4, 6, 8 s), only the noise's change (sd 1.5-4 mN, AR(1))
    steps = []
    for rec in recs:
        y, t = rec.samples[:, CHANNELS.index("index_x")], rec.t
        for join in (2.0, 4.0, 6.0, 8.0):
            before = y[(t >= join - 0.02) & (t < join)]
            after = y[(t >= join) & (t < join + 0.02)]
            if np.isfinite(before).all() and np.isfinite(after).all():
                steps.append(abs(after.mean() - before.mean()))
    assert len(steps) > 20 and np.median(steps) < 0.003 and max(steps) < 0.01


def test_truth_per_motion_and_channel(recs):
    truth = recs[2].truth
    assert len(truth["motions"]) == 5
    m = truth["motions"][1]
    assert set(m["channels"]) == set(CHANNELS)
    start, stop = m["move_out"]
    assert 2.05 < start < 2.1 and 0.09 < stop - start < 0.17  # latency, movement 100-150 ms
    thumb, index = m["channels"]["thumb_x"], m["channels"]["index_x"]
    assert thumb["direction"] == -1.0 and index["direction"] == 1.0
    # forces scale with each channel's gain; time constants do not
    assert thumb["f_kin"] / index["f_kin"] == pytest.approx(abs(thumb["gain"] / index["gain"]))
    assert thumb["tau"] == index["tau"]


def test_measurement_truth_is_what_a_whole_fit_estimates(recs):
    rec = dataclasses.replace(recs[2], truth=copy.deepcopy(recs[2].truth))
    for i, m in enumerate(rec.truth["motions"]):
        m["channels"]["index_x"]["f_kin"] = 2.0 * 0.99**i  # wearing 1 % per motion
        m["channels"]["index_x"]["k"] = [50.0, 1.0, 2.0, 3.0, 4.0][i]
        m["channels"]["thumb_x"]["k"] = 7.0
    # f_kin: the trend through the fitted motions (1-4) halfway through the travel, the end
    # of motion 2's out stroke, a quarter motion before the middle of motion 2's level
    assert measurement_truth(rec, "f_kin") == pytest.approx(2.0 * 0.99**1.75, rel=1e-12)
    assert measurement_truth(rec, "k") == 2.5  # median over the fitted motions
    assert measurement_truth(rec, "k", "thumb_x") == 7.0


def test_faults_are_present_and_flagged_on_read(tmp_path):
    recs = simulate_measurements([(1, c, t) for c in CLASSES[:4] for t in (1, 2)], seed=5,
                                 pad_to=PAD)
    faults = [f for r in recs for f in r.truth["faults"]]
    assert {f["kind"] for f in faults} >= {"nan", "drop"}
    assert 0.05 < len(faults) / (5 * len(recs)) < 0.4  # about 1 motion in 6
    for rec in recs:
        kinds = {f["kind"] for f in rec.truth["faults"]}
        if not kinds & {"nan", "drop"}:
            continue
        back = read_recording(write_recording(rec, tmp_path / rec.name, decimals=3),
                              on_error="flag")
        flagged = {p.kind for p in back.problems}
        assert ("nan" not in kinds or "nonfinite" in flagged)
        assert ("drop" not in kinds or "gap" in flagged)


def test_round_trip_of_the_written_dataset(tmp_path, recs):
    paths = simulate_dataset(tmp_path, seed=5, sessions=2, measurements_per_class=1,
                             classes=["paper-1", "cushion-1"], batch=8)
    assert [p.name for p in paths] == ["s1_paper-1_01.csv", "s1_cushion-1_01.csv",
                                       "s2_paper-1_01.csv", "s2_cushion-1_01.csv"]
    back = {r.name: r for r in read_dataset(tmp_path)}
    mine = {r.name: r for r in recs}
    for name in ("s1_paper-1_01", "s2_cushion-1_01"):  # same seed, spec: same measurement
        np.testing.assert_array_equal(back[name].samples, mine[name].samples)
        np.testing.assert_array_equal(back[name].t, mine[name].t)
        assert back[name].metadata == mine[name].metadata
        assert back[name].events == mine[name].events
        assert back[name].truth == json.loads(json.dumps(mine[name].truth))


def test_same_seed_same_bytes(tmp_path):
    kw = dict(sessions=1, measurements_per_class=1, classes=["belt-2"], batch=8)
    a = simulate_dataset(tmp_path / "a", seed=3, **kw)[0]
    b = simulate_dataset(tmp_path / "b", seed=3, **kw)[0]
    c = simulate_dataset(tmp_path / "c", seed=4, **kw)[0]
    assert a.read_bytes() == b.read_bytes()
    assert a.with_suffix(".json").read_bytes() == b.with_suffix(".json").read_bytes()
    assert a.read_bytes() != c.read_bytes()


def test_bad_arguments_are_named(tmp_path):
    with pytest.raises(ValueError, match="unknown class 'felt-1'"):
        simulate_dataset(tmp_path, classes=["felt-1"])
    with pytest.raises(ValueError, match="sessions and measurements_per_class must be >= 1"):
        simulate_dataset(tmp_path, sessions=0)
