"""Parameter priors: the fit is the MAP estimate, the posterior carries the same prior."""

import numpy as np
import pytest
from typer.testing import CliRunner

from frictionfit.cli import app
from frictionfit.errors import FitError
from frictionfit.fit import fit_report, fit_trials
from frictionfit.models import get_model
from frictionfit.simulation.trials import simulate_trials
from frictionfit.uncertainty import sample_posterior

RELAX = "relaxation"


@pytest.fixture(scope="module")
def trials():
    return simulate_trials(RELAX, 24, seed=11)


def _fit(ts, **kw):
    return fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model=RELAX, direction=ts.direction,
                      chunk_size=8, **kw)


def _median_error(res, ts, name):
    est = res.values[name].to_numpy()
    return float(np.median(np.abs(est - ts.truth[name]) / ts.truth[name]))


def test_default_movement_prior_pins_the_stiffness_ridge(trials):
    flat = _fit(trials, priors={"ramp": None})
    default = _fit(trials)
    # The onset only fixes k / ramp**2: without the prior the fit wanders along that ridge.
    assert _median_error(default, trials, "k") < 0.6 * _median_error(flat, trials, "k")
    assert _median_error(default, trials, "ramp") < _median_error(flat, trials, "ramp")
    # Parameters the data pin alone do not move.
    for name in ("f_kin", "relax_frac", "tau"):
        assert _median_error(default, trials, name) < 0.08


def test_strong_prior_wins_and_posterior_carries_it(trials):
    ts = simulate_trials(RELAX, 2, seed=12)
    res = _fit(ts, priors={"ramp": (0.2, 0.005)})
    ramps = res.values["ramp"].to_numpy()
    np.testing.assert_allclose(ramps, 0.2, rtol=0.02)  # truth is 0.10-0.15 s
    post = sample_posterior(res, ts.y, ts.t, (ts.t_out, ts.t_back), method="laplace")
    sd = np.array([post.sd[i]["ramp"] for i in range(2)])
    assert np.all(sd < 0.2 * 0.0055)  # not wider than the prior itself


def test_report_lists_priors_and_bad_priors_are_named(trials):
    ts = simulate_trials(RELAX, 1, seed=13)
    res = _fit(ts, priors={"ramp": (0.15, 0.2)})
    assert "ramp             median 0.15 s, log sd 0.2" in fit_report(res, 0)
    assert get_model(RELAX, priors={"ramp": None}).prior_table == {"slip_length": (0.05, 1.5)}
    assert get_model(RELAX, priors={"ramp": None, "slip_length": None}).prior_table == {}
    with pytest.raises(FitError, match="ramp"):
        _fit(ts, priors={"ramp": (2.0, 0.3)})  # outside the bounds (0.005, 1) s
    with pytest.raises(FitError, match="no parameter 'stiffness'"):
        _fit(ts, priors={"stiffness": (5.0, 0.3)})


def test_cli_prior_option_is_checked(tmp_path):
    result = CliRunner().invoke(app, ["fit", str(tmp_path), "--prior", "ramp=0.1"])
    assert result.exit_code == 2 and "NAME=CENTRE,SD" in result.output
