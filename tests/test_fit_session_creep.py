"""The finger's creep held per session (``creep="session"``) and the relaxation quantities
left out of the physical features (``relaxation=False``)."""

from __future__ import annotations

import numpy as np
import pytest

from frictionfit import fit_recordings
from frictionfit.features.physical import PhysicalFeatures
from frictionfit.simulation.measurements import simulate_measurements


@pytest.fixture(scope="module")
def session():
    """Three measurements of one session (three materials) and one of another session."""
    specs = [(1, "paper-1", 1), (1, "cushion-1", 1), (1, "aluminium-foil-1", 1),
             (2, "paper-2", 1)]
    return simulate_measurements(specs, seed=5)


def test_the_creep_is_one_per_session_and_channel_with_its_spread_in_the_stderrs(session):
    free = fit_recordings(session, channels=["index_x"], model="relaxation2",
                          fix={"wear": 0.0}, progress=False)
    held = fit_recordings(session, channels=["index_x"], model="relaxation2",
                          fix={"wear": 0.0}, creep="session", progress=False)
    tau2 = held.values["tau2"].to_numpy()
    # the session's three share the median of their free fits; the lone one keeps its own
    np.testing.assert_allclose(tau2[:3], np.median(free.values["tau2"].to_numpy()[:3]),
                               rtol=1e-9)
    assert tau2[3] == pytest.approx(free.values["tau2"].to_numpy()[3], rel=1e-6)
    assert all(flags.get("tau2") != "at bound" for flags in held.flags)
    # the held value's own spread reaches the free parameters: k's stderr is finite and > 0
    assert np.all(np.isfinite(held.stderr["k"])) and np.all(held.stderr["k"] > 0)


def test_a_lone_recording_is_fitted_as_with_its_creep_free(session):
    one = fit_recordings(session[0], channels=["index_x"], model="relaxation2",
                         fix={"wear": 0.0}, progress=False)
    same = fit_recordings(session[0], channels=["index_x"], model="relaxation2",
                          fix={"wear": 0.0}, creep="session", progress=False)
    np.testing.assert_array_equal(one.values.to_numpy(), same.values.to_numpy())


def test_an_unknown_creep_level_is_refused(session):
    with pytest.raises(ValueError, match="creep must be 'session' or 'recording'"):
        fit_recordings(session[0], channels=["index_x"], creep="day", progress=False)


def test_the_relaxation_quantities_are_left_out_unless_asked_for():
    names = PhysicalFeatures(fitted=True, relaxation=True).get_feature_names_out()
    kept = PhysicalFeatures(fitted=True).get_feature_names_out()
    gone = sorted(set(names) - set(kept))
    assert len(names) == 110 and len(kept) == 56
    assert {n.split(":")[1].split(" ")[0] for n in gone} == {
        "fit_relax_frac", "fit_tau", "fit_drag", "out_relaxed_frac", "back_relaxed_frac",
        "out_t_relax", "back_t_relax", *(f"{p}_relax_{ms}ms" for p in ("out", "back")
                                         for ms in (50, 100, 200, 400))}
    assert "index_x:fit_k [log10 N/mm]" in kept and "index_x:out_onset_rate [N/s]" in kept
    with_errors = PhysicalFeatures(fitted=True, with_stderr=True).get_feature_names_out()
    assert not [n for n in with_errors if "relax" in n or "tau" in n or "drag" in n]
