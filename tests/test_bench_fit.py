"""bench fit: the NumPy peers' models are the JAX models; the quick run has the agreed shape."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from frictionfit.bench.fit import numpy_predict, run
from frictionfit.bench.measurement import COST_TIE, numpy_residual
from frictionfit.fit import measurement_data
from frictionfit.fit._whole_problem import residual_fn, stack_items
from frictionfit.models import FAMILY, PARAMS, MeasurementModel
from frictionfit.models.measurement import to_unconstrained
from frictionfit.simulation.measurements import simulate_measurements

VALUES = dict(offset=-0.2, k=12.0, f_kin=0.7, f_static_excess=0.3, slip_length=0.04,
              relax_frac=0.35, tau=0.12, relax_frac2=0.2, tau2=1.1, damping=4e-3,
              delay=0.025, ramp=0.13)


@pytest.mark.parametrize("model", FAMILY, ids=lambda m: m.name)
def test_numpy_twin_equals_jax_model(model):
    t = np.arange(2000) / 1000.0
    u = np.array([PARAMS[n].to_unconstrained(VALUES[n]) for n in model.param_names])
    twin = numpy_predict(model, u, t, 0.05, 1.05, -1.0)
    ref = np.asarray(model.predict(jnp.asarray(u), jnp.asarray(t), (0.05, 1.05), -1.0))
    # Same recurrence, same operation order: agreement to rounding (1e-10 N is the bar).
    np.testing.assert_allclose(twin, ref, rtol=0, atol=1e-10)
    assert np.ptp(ref) > 0.1  # the trial actually moves (a flat signal would agree trivially)


@pytest.mark.slow
def test_quick_run_reports_every_summary_number():
    out = run(quick=True, seed=0)
    assert out["stage"] == "fit"
    for key in ("trials_per_s", "speedup_vs_scipy_numpy", "speedup_vs_scipy_jax",
                "median_rel_error", "scipy_median_rel_error", "success_rate", "compile_s"):
        assert isinstance(out["summary"][key], float) and np.isfinite(out["summary"][key]), key
    assert {"config", "seconds_per_trial", "error", "error_name", "success_rate"} <= set(
        out["points"][0])
    assert out["machine"]["cpu_count"] >= 1
    meas = out["summary"]["measurements"]  # whole-measurement truth recovery
    assert meas["recordings_per_s"] > 0 and 0 <= meas["converged_rate"] <= 1
    assert set(meas["median_rel_error_by_param"]) >= {"k", "f_kin", "f_static_excess",
                                                      "relax_frac", "tau"}
    assert meas["median_rel_error_by_param"]["k"] < 0.2  # per-motion fits: ~50x off
    numpy_peer = meas["peers"]["scipy-numpy"]  # scipy's LM on the objective in plain NumPy
    assert numpy_peer["n_recordings"] == 2 and numpy_peer["s_per_recording"] > 0
    # The speed ratios compare like with like: ours reaches the peers' optimum (a median
    # recording's cost within a tie of theirs, or lower).
    for peer in meas["peers"].values():
        assert peer["median_cost_rel_diff"] <= COST_TIE
    assert meas["peers"]["scipy-jax"]["n_recordings"] == 8  # every recording, up to PEER_N
    rigs = out["summary"]["rigs"]  # the material through each simulated rig
    assert set(rigs) == {"sim-a", "sim-b", "sim-c"}
    assert all(r["n_recordings"] == 8 and set(r["median_rel_error_by_param"]) >= {
        "k", "f_kin", "relax_frac", "tau"} for r in rigs.values())


@pytest.fixture(scope="module")
def measurement():
    rec, = simulate_measurements([(1, "carpet-1", 1)], seed=5)
    return measurement_data(rec, "index_x")


@pytest.mark.parametrize("law", ["relaxation2", "no_peak2"])
def test_numpy_measurement_residual_equals_jax_residual(law, measurement):
    model = MeasurementModel(law)
    residual = residual_fn(model, tuple(range(model.n_params)))
    residual = jax.jit(residual)
    start = to_unconstrained(model, measurement.guess)
    # Points near the guess, not the guess itself: at its round values (accel 0.1) the JAX
    # drive can end a movement one ulp back, a reversal that resets the law's slip, and
    # NumPy rounds the parameters' exp/tanh differently from XLA (there: a few 1e-9 relative).
    for u in start + 0.3 * np.random.default_rng(0).standard_normal((3, start.size)):
        data = jax.tree_util.tree_map(jnp.asarray, stack_items([measurement], u[None]).take(0))
        ref = np.asarray(residual(jnp.asarray(u), data))
        twin = numpy_residual(model, u, measurement)
        np.testing.assert_allclose(twin, ref, rtol=0, atol=1e-9 * np.max(np.abs(ref)))


@pytest.mark.slow
def test_solver_paths_measure_each_path_on_the_same_trials():
    from frictionfit.bench.fit import _solver_paths
    from frictionfit.fit import initial_guess
    from frictionfit.models import get_model
    from frictionfit.simulation.trials import simulate_trials

    ts = simulate_trials("elastic_plastic", 8, seed=0)
    model = get_model("elastic_plastic")
    u0 = initial_guess(model, ts.t, ts.y, np.full(8, ts.t_out), np.full(8, ts.t_back),
                       ts.direction)
    points, summary = _solver_paths(ts, model, u0, 4, reps=1)
    assert [p["config"] for p in points] == [
        f"{k} elastic_plastic threads=1"
        for k in ("lm driver", "optx-lm driver", "optx-lm rounds")]
    assert points[0]["success_rate"] >= 0.75
    for key in ("lm_driver_trials_per_s", "optx_lm_driver_over_rounds",
                "optx_lm_rounds_trials_per_s", "optx_lm_driver_success_rate"):
        assert np.isfinite(summary[key]) and summary[key] > 0, key
