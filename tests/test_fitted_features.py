"""The lateral channels' fitted gain and slip noise: recovered where they are known."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from frictionfit.features.physical import FittedFeatures, PhysicalFeatures
from frictionfit.fit import MeasurementData
from frictionfit.fit.derived import SLIP_S, _band_rms
from frictionfit.fit.lateral import LATERAL, fit_lateral
from frictionfit.fit.lateral import _regressors_fn as regressors
from frictionfit.models import MeasurementModel
from frictionfit.models.measurement import to_unconstrained
from frictionfit.simulation.measurements import simulate_measurements

MODEL = MeasurementModel("relaxation2")
TRUTH = {"offset": 0.2, "drift": -0.01, "leak": 0.05, "gain": -0.3}


def _drive():
    """Five out-back motions at the protocol's times, 1 kHz for 10 s."""
    commands = 0.05 + np.arange(10.0)
    return commands, np.tile([1.0, -1.0], 5), np.arange(0.0, 10.05, 1e-3)


def _lateral(seed: int, noise: float, shaking: float = 0.0):
    """A lateral channel that follows the lateral law with :data:`TRUTH` plus AR(1) noise and
    a 70 Hz sine of amplitude ``shaking`` (N) for ``SLIP_S`` after every command."""
    u = to_unconstrained(MODEL, {"k": 20.0, "f_kin": 1.0, "f_static_excess": 0.3,
                                 "relax_frac": 0.3, "tau": 0.2, "offset": 0.7, "leak": 0.1})
    commands, signs, t = _drive()
    force, travel = (np.asarray(a) for a in regressors(MODEL)(u, t, commands, signs,
                                                                    np.ones_like(commands), -1.0))
    rng = np.random.default_rng(seed)
    e = rng.standard_normal(t.size) * noise
    for i in range(1, t.size):  # AR(1) noise, as the lab's residuals are
        e[i] += 0.8 * e[i - 1]
    y = (TRUTH["offset"] + TRUTH["drift"] * t + TRUTH["leak"] * travel + TRUTH["gain"] * force
         + e)
    for c in commands:
        window = (t >= c) & (t < c + SLIP_S)
        y[window] += shaking * np.sin(2 * np.pi * 70.0 * (t[window] - c))
    weight = (t >= commands[2]).astype(float)  # the first motion is not fitted
    return u, commands, signs, _data(t, y, weight, commands, signs, noise)


def _data(t, y, weight, commands, signs, noise) -> MeasurementData:
    return MeasurementData("synthetic", "index_y", t, y, weight, max(noise, 1e-6), commands,
                           signs, 1.0, {})


def test_lateral_law_recovered_with_its_stderr():
    z = []
    for seed in range(8):
        u, commands, signs, d = _lateral(seed, noise=0.01)
        got = fit_lateral(MODEL, u, d.drive, -1.0, d)
        values, stderr = ({n: v[j] for n, v in got.items()} for j in (0, 1))
        assert values["gain"] == pytest.approx(TRUTH["gain"], abs=0.01)
        assert values["leak"] == pytest.approx(TRUTH["leak"], abs=0.01)
        assert 0 < stderr["gain"] < 0.01
        z.append([(values[n] - TRUTH[n]) / stderr[n] for n in LATERAL])
    assert np.all(np.abs(z) < 4)  # the AR(1)-inflated stderr is not too narrow


def test_lateral_law_without_noise_is_exact():
    u, commands, signs, d = _lateral(0, noise=0.0)
    got = fit_lateral(MODEL, u, d.drive, -1.0, d)
    assert [got[n][0] for n in LATERAL] == pytest.approx([TRUTH[n] for n in LATERAL], abs=1e-8)
    assert got["slip_noise"][0] == pytest.approx(0.0, abs=1e-6)


def test_lateral_slip_noise_measures_shaking_the_law_cannot_follow():
    amplitude = 0.02  # N
    expected = _band_rms(amplitude * np.sin(2 * np.pi * 70.0 * np.arange(0.0, SLIP_S, 1e-3)))
    u, commands, signs, d = _lateral(1, noise=0.001, shaking=amplitude)
    noise, se = fit_lateral(MODEL, u, d.drive, -1.0, d)["slip_noise"]
    assert noise == pytest.approx(expected, rel=0.2)
    assert 0 < se < 0.2 * noise
    u, commands, signs, d = _lateral(1, noise=0.001)
    assert fit_lateral(MODEL, u, d.drive, -1.0, d)["slip_noise"][0] < 0.2 * expected


def test_lateral_law_with_too_few_blocks_is_nan():
    u, commands, signs, d = _lateral(0, noise=0.01)
    d = dataclasses.replace(d, weight=np.where(d.t < 0.01, 1.0, 0.0))
    got = fit_lateral(MODEL, u, d.drive, -1.0, d)
    assert all(np.isnan(v) for pair in got.values() for v in pair)


def test_gain_columns_only_where_the_rubbing_channel_is_fitted():
    names = list(FittedFeatures(with_stderr=True).get_feature_names_out())
    assert "thumb_y:fit_gain [1]" in names and "index_y:fit_gain_stderr [1]" in names
    assert "thumb_y:fit_slip_noise [log10 N]" in names
    alone = PhysicalFeatures(fitted=True, channels=("thumb_y", "index_x", "index_y"))
    assert not any(n.startswith("thumb_y:fit_") for n in alone.get_feature_names_out())
    assert "index_y:fit_gain [1]" in alone.get_feature_names_out()


def test_fitted_gain_of_a_lateral_channel_proportional_to_the_rubbing_one():
    rec, = simulate_measurements([(1, "carpet-1", 1)], seed=5)
    samples = np.array(rec.samples, dtype=np.float64)
    names = rec.channel_names
    x = samples[:, names.index("index_x")]
    noise = np.random.default_rng(0).standard_normal(x.size) * 0.002
    samples[:, names.index("index_y")] = 0.4 - 0.25 * x + noise
    rec = dataclasses.replace(rec, samples=samples)
    f = FittedFeatures(channels=("index_x", "index_y"), with_stderr=True, cache=False)
    row = dict(zip(f.fit([rec]).get_feature_names_out(), f.transform([rec])[0], strict=True))
    # the lateral channel is -0.25 times the rubbing one: offset, drift and leak included
    assert row["index_y:fit_gain [1]"] == pytest.approx(-0.25, abs=0.01)
    assert 0 < row["index_y:fit_gain_stderr [1]"] < 0.01
    assert np.isfinite(row["index_y:fit_slip_noise [log10 N]"])


def test_a_recordings_fitted_features_do_not_depend_on_what_is_featurised_with_it():
    recs = simulate_measurements([(1, "carpet-1", 1), (1, "paper-2", 1), (1, "scarf-1", 1)],
                                 seed=7)
    together = FittedFeatures(cache=False).fit_transform(recs)
    alone = FittedFeatures(cache=False).fit_transform(recs[1:2])
    assert np.isfinite(alone).all()
    np.testing.assert_allclose(alone[0], together[1], rtol=1e-6, atol=1e-9)


def test_the_features_fits_take_no_second_start_from_their_batch(monkeypatch):
    # a second start from the session's profile is computed over the batch (five or more
    # fits of a session): the row of a recording would then depend on its batch-mates
    import frictionfit.whole_fit as whole_fit

    seen = []
    fit = whole_fit.fit_recordings

    def spy(*args, **kwargs):
        seen.append(kwargs.get("refit_rig_outliers", True))
        return fit(*args, **kwargs)

    monkeypatch.setattr(whole_fit, "fit_recordings", spy)
    recs = simulate_measurements([(1, "paper-2", 1)], seed=7)
    FittedFeatures(cache=False).fit_transform(recs)
    assert seen == [False]


def _with_stroke(rec, stroke_mm):
    return dataclasses.replace(rec, metadata=rec.metadata | {"stroke_mm": stroke_mm})


def test_stiffness_is_per_mm_of_the_declared_stroke_and_named_per_stroke_without_one():
    rec, = simulate_measurements([(1, "paper-2", 1)], seed=7)
    bare = FittedFeatures(channels=("index_x",), relaxation=True, cache=False)
    row = bare.fit_transform([rec])[0]
    names = list(bare.get_feature_names_out())
    assert "index_x:fit_k [log10 N/stroke]" in names  # no stroke declared: no false N/mm
    assert "index_x:fit_drag [log10 N s/stroke]" in names
    declared = FittedFeatures(channels=("index_x",), relaxation=True, cache=False)
    row_mm = declared.fit_transform([_with_stroke(rec, 13.0)])[0]
    assert "index_x:fit_k [log10 N/mm]" in list(declared.get_feature_names_out())
    per_stroke = dict(zip(names, row, strict=True))
    per_mm = dict(zip(declared.get_feature_names_out(), row_mm, strict=True))
    # the same fit: k over the stroke, the friction levels as they are
    assert per_mm["index_x:fit_k [log10 N/mm]"] == pytest.approx(
        per_stroke["index_x:fit_k [log10 N/stroke]"] - np.log10(13.0), abs=1e-12)
    assert per_mm["index_x:fit_f_held [log10 N]"] == per_stroke["index_x:fit_f_held [log10 N]"]
    with pytest.raises(ValueError, match="these do not \\(declare metadata.stroke_mm\\)"):
        declared.transform([rec])


def test_recordings_with_and_without_a_stroke_are_not_mixed():
    a, b = simulate_measurements([(1, "paper-2", 1), (1, "carpet-1", 1)], seed=7)
    with pytest.raises(ValueError, match=r"1 recording\(s\) declare no rig stroke.*s1_carpet"):
        FittedFeatures(cache=False).fit([_with_stroke(a, 9.0), b])
