"""The grip as a measured input: load, load-free taxels, power laws of the grip, per-grip scores."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from frictionfit.datasets.fabricslide import PROXIMITY, TAXELS
from frictionfit.errors import RecordingError
from frictionfit.features.grip import (
    GripLaw,
    breakaway_shift,
    grip_load,
    law_curve,
    law_support,
    load_signal,
    stroke_shift,
    without_load,
)
from frictionfit.recording import Recording

RATE_HZ = 35.6


def slide(load: float, rng, offsets=None, speed: float = -100.0, texture_hz: float = 1.5,
          name: str = "Canvas_F150_V-100mmps_0") -> Recording:
    """Taxels that follow a slowly oscillating load (each by its own gain) plus a texture."""
    n = int(594.2 / abs(speed) * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    gains = rng.uniform(0.5, 1.5, 16)
    level = load * gains / gains.mean()
    swing = 0.05 * load * np.sin(2 * np.pi * 0.3 * t)
    texture = ((t * texture_hz) % 1.0)[:, None] * rng.uniform(-3, 3, 16)
    taxels = level + swing[:, None] * gains + texture + rng.normal(0, 0.3, (n, 16))
    if offsets is not None:
        taxels = taxels + offsets
    prox = np.column_stack([np.full(n, 40.0), np.full(n, 65535.0)])
    meta = {"label": "Canvas", "dataset": "fabricslide", "speed": speed,
            "ramp_s": 47.1 / abs(speed)}
    return Recording.from_arrays(np.hstack([taxels, prox]), RATE_HZ, [*TAXELS, *PROXIMITY],
                                 units="counts", metadata=meta, name=name)


def test_grip_load_is_the_trimmed_mean_of_the_taxel_means():
    rec = slide(180.0, np.random.default_rng(0))
    keep = (rec.t >= rec.metadata["ramp_s"]) & (rec.t <= rec.t[-1] - rec.metadata["ramp_s"])
    means = np.sort([rec.channel(c)[keep].mean() for c in TAXELS])
    assert grip_load(rec) == pytest.approx(means[1:-1].mean(), rel=1e-12)
    assert grip_load(rec) == pytest.approx(180.0, rel=0.05)
    with pytest.raises(RecordingError, match="Canvas_F150_V-100mmps_0: grip load -.* counts "
                                             "is not positive"):
        grip_load(Recording.from_arrays(-np.abs(rec.samples), RATE_HZ, rec.channel_names,
                                        units="counts", metadata=rec.metadata, name=rec.name))


def test_load_free_taxels_keep_the_texture_and_ignore_offsets():
    rng = np.random.default_rng(1)
    rec = slide(200.0, rng)
    x = np.column_stack([rec.channel(c) for c in TAXELS])
    free = without_load(x)
    n = load_signal(x)
    assert np.abs(n @ free).max() < 1e-6 * np.abs(n @ (x - x.mean(axis=0))).max()
    # the load's swing (10 counts on every taxel) is gone; the sawtooth texture stays
    assert free.std(axis=0).mean() < 0.5 * (x - x.mean(axis=0)).std(axis=0).mean()
    np.testing.assert_allclose(without_load(x + rng.uniform(-80, 300, 16)), free, atol=1e-9)


def test_grip_law_recovers_a_common_exponent_within_classes():
    rng = np.random.default_rng(2)
    classes = np.repeat(["a", "b", "c"], 40)
    log_load = np.log(rng.uniform(120, 250, classes.size))
    intercept = {"a": 0.0, "b": 1.0, "c": -2.0}
    q = np.column_stack([
        [intercept[c] for c in classes] + (1 / 3) * log_load + rng.normal(0, 0.01, classes.size),
        [intercept[c] for c in classes] + rng.normal(0, 0.01, classes.size)])
    law = GripLaw().fit(q, classes, log_load=log_load)
    np.testing.assert_allclose(law.exponents_, [1 / 3, 0.0], atol=0.02)
    at_ref = law.transform(q, log_load=log_load)
    for c in intercept:  # brought to the reference load, each class is one point again
        assert at_ref[classes == c, 0].std() < 0.02
    assert np.all(GripLaw().fit(q, None, log_load=log_load).exponents_ == 0)
    with pytest.raises(ValueError, match=r"log_load needs one finite value per row \(120\)"):
        GripLaw().fit(q, classes, log_load=log_load[:-1])


def test_law_support_prefers_the_law_that_made_the_data():
    """Three fabrics following three laws; grasp-to-grasp scatter 0.02, row noise 0.005."""
    truth = {"Felt": "per_unit_load", "Silk": "hertz", "Wool": "constant"}
    exponent = {"Felt": 1.0, "Silk": 1 / 3, "Wool": 0.0}
    chosen = []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        rows = []
        for fabric, b in exponent.items():
            for p in (120, 150, 180, 210, 250):
                grasp = rng.normal(0, 0.02)
                for _ in range(4):
                    load = p * rng.uniform(0.97, 1.03)
                    rows.append({"fabric": fabric, "pressure": p, "log_load": np.log(load),
                                 "q": 2.0 + grasp + b * np.log(load) + rng.normal(0, 0.005)})
        table = law_support(pd.DataFrame(rows), ["q"])
        assert set(table["n_grips"]) == {5}
        power = table[table["law"] == "power"].set_index("fabric")["exponent"]
        np.testing.assert_allclose(power[list(exponent)], list(exponent.values()), atol=0.1)
        chosen += [(f, b) for f, b in table.drop_duplicates("fabric")[["fabric", "best"]]
                   .itertuples(index=False)]
    # never a wrong law; the free power law (which holds the truth) at most now and then
    assert all(b in (truth[f], "power") for f, b in chosen)
    assert sum(b == truth[f] for f, b in chosen) >= 0.75 * len(chosen)


def test_left_out_scores_say_where_each_left_out_value_lies():
    from frictionfit.classify import Evaluation, left_out_scores

    pred = pd.DataFrame({"true": list("aabbaabbab"), "predicted": list("aabbabbbbb"),
                         "pressure": [120] * 4 + [180] * 4 + [250] * 2})
    ev = Evaluation(accuracy=0.7, macro_f1=0.7, confusion=pd.DataFrame(), predictions=pred)
    table = left_out_scores(ev, "pressure")
    assert table.to_dict("list") == {
        "pressure": [120, 180, 250], "accuracy": [1.0, 0.75, 0.5], "n": [4, 4, 2],
        "trained_on": ["180-250", "120-250", "120-180"], "where": ["below", "inside", "above"]}
    with pytest.raises(ValueError, match="the predictions have no 'session' column"):
        left_out_scores(ev, "session")


def test_evaluate_reports_each_left_out_pressure(tmp_path):
    from typer.testing import CliRunner

    from frictionfit.cli import app
    from tests.test_fabricslide import write_slide

    for fabric in ("Canvas", "Linen"):
        for p in (120, 150, 180):
            for rep in (0, 1, 2):
                write_slide(tmp_path / f"{fabric}_F{p}_V-100mmps_{rep}.csv", n=60,
                            rng=np.random.default_rng([p, rep, len(fabric)]))
    result = CliRunner().invoke(app, [
        "evaluate", "--dataset", f"fabricslide:{tmp_path}", "--features", "shortcut",
        "--no-calibrate", "--protocols", "leave-one-pressure-out,leave-one-repetition-out"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    for p, span, where in ((120, "150-180", "below"), (150, "120-180", "inside"),
                           (180, "120-150", "above")):
        assert any(f"left out pressure {p} (trained on {span}, {where} the training "
                   f"pressures): accuracy" in line and "(n 6)" in line for line in lines)
    assert any("left out repetition 2 (trained on 0-1, above" in line for line in lines)
    assert lines[-1].startswith("accuracy: ")


def test_law_curve_fits_and_evaluates_a_named_law():
    log_l = np.log([120.0, 150.0, 180.0, 210.0])
    q = 0.5 + log_l / 3
    np.testing.assert_allclose(law_curve("hertz", log_l, q, np.log([250.0])),
                               0.5 + np.log(250.0) / 3, rtol=1e-12)
    np.testing.assert_allclose(law_curve("power", log_l, q, log_l), q, rtol=1e-12)
    with pytest.raises(ValueError, match="unknown law 'cubic'; choose from"):
        law_curve("cubic", log_l, q, log_l)


def test_a_model_file_may_hold_a_fitted_grip_law(tmp_path):
    from frictionfit.model_file import load_model, save_model

    law = GripLaw().fit(np.eye(4), list("aabb"), log_load=np.log([120.0, 150.0, 120.0, 150.0]))
    from sklearn.svm import SVC

    save_model({"pipeline": SVC(), "grip_law": law}, tmp_path / "m.skops")
    np.testing.assert_array_equal(load_model(tmp_path / "m.skops")["grip_law"].exponents_,
                                  law.exponents_)


def test_breakaway_shift_grows_with_the_load_and_ignores_offsets():
    """Shear shifting load between taxels (gains summing to zero) as the slide starts,
    0.2 of the grip load (friction-like), on top of a level and a common swing."""
    rng = np.random.default_rng(5)
    gains = rng.uniform(0.5, 1.5, 16) * np.tile([1.0, -1.0], 8)
    gains -= gains.mean()
    shifts = []
    for load in (120.0, 240.0):
        rec = slide(load, np.random.default_rng(6))
        x = np.column_stack([rec.channel(c) for c in TAXELS])
        shear = 0.2 * load * np.minimum(rec.t / rec.metadata["ramp_s"], 1.0)
        rec = Recording.from_arrays(x + shear[:, None] * gains, RATE_HZ, list(TAXELS),
                                    units="counts", metadata=rec.metadata, name=rec.name)
        shifts.append(breakaway_shift(rec))
        moved = Recording.from_arrays(rec.samples + rng.uniform(-80, 300, 16), RATE_HZ,
                                      list(TAXELS), units="counts", metadata=rec.metadata)
        assert breakaway_shift(moved) == pytest.approx(shifts[-1], rel=1e-9)
    # the shear reaches 0.2 L; the first 3 % of the slide see ~a fifth of it
    assert np.log(shifts[1] / shifts[0]) / np.log(2.0) == pytest.approx(1.0, abs=0.1)
    assert shifts[0] == pytest.approx(0.2 * 120 * np.linalg.norm(gains), rel=0.3)
    flat = Recording.from_arrays(np.ones((200, 16)), RATE_HZ, list(TAXELS), units="counts",
                                 metadata=rec.metadata, name="flat")
    with pytest.raises(RecordingError, match="flat: breakaway shift 0 counts is not positive"):
        breakaway_shift(flat)


def test_stroke_shift_grows_with_the_load_and_ignores_offsets():
    """Load shifted between taxels (gains summing to zero) steadily over the stroke, up to
    0.2 of the grip load (friction-like), on top of a level and a common swing."""
    rng = np.random.default_rng(7)
    gains = rng.uniform(0.5, 1.5, 16) * np.tile([1.0, -1.0], 8)
    gains -= gains.mean()
    shifts = []
    for load in (120.0, 240.0):
        rec = slide(load, np.random.default_rng(8))
        x = np.column_stack([rec.channel(c) for c in TAXELS])
        shear = 0.2 * load * rec.t / rec.t[-1]
        rec = Recording.from_arrays(x + shear[:, None] * gains, RATE_HZ, list(TAXELS),
                                    units="counts", metadata=rec.metadata, name=rec.name)
        shifts.append(stroke_shift(rec))
        moved = Recording.from_arrays(rec.samples + rng.uniform(-80, 300, 16), RATE_HZ,
                                      list(TAXELS), units="counts", metadata=rec.metadata)
        assert stroke_shift(moved) == pytest.approx(shifts[-1], rel=1e-9)
    assert np.log(shifts[1] / shifts[0]) / np.log(2.0) == pytest.approx(1.0, abs=0.1)
    # the ramps' means lie ~92 % of the stroke apart (each ramp ~7.9 % of the slide)
    assert shifts[0] == pytest.approx(0.92 * 0.2 * 120 * np.linalg.norm(gains), rel=0.15)
    flat = Recording.from_arrays(np.ones((200, 16)), RATE_HZ, list(TAXELS), units="counts",
                                 metadata=rec.metadata, name="flat")
    with pytest.raises(RecordingError, match="flat: stroke shift 0 counts is not positive"):
        stroke_shift(flat)
