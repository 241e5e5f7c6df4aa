"""The refilling pool driver: any optimistix solver in it equals that solver one problem at a
time; failures end in a status."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from helpers import hard_cases, known_truth

from frictionfit.errors import FitError, Status
from frictionfit.fit import BatchedLevenbergMarquardt, fit_trials
from frictionfit.fit._optx import RESULT_STATUS, solve_pooled
from frictionfit.models.measurement import HOST_LOOP_COMPILER_OPTIONS

SOLVERS = {"optx-lm": optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10),
           "dogleg": optx.Dogleg(rtol=1e-10, atol=1e-10),
           "gauss-newton": optx.GaussNewton(rtol=1e-10, atol=1e-10),
           "lm": BatchedLevenbergMarquardt()}


def _saturation(b, args):
    x, y = args
    return b[0] * (1 - jnp.exp(-b[1] * x)) - y


def _problems(n=7, seed=0):
    """``n`` noisy saturation curves with starts from near to far (1/20 to 20 times the
    rate), so that problems need different numbers of steps."""
    rng = np.random.default_rng(seed)
    x = np.tile(np.linspace(0.1, 5.0, 40), (n, 1))
    a, b = rng.uniform(1, 3, n), rng.uniform(0.2, 2, n)
    y = a[:, None] * (1 - np.exp(-b[:, None] * x)) + 0.01 * rng.normal(size=x.shape)
    y0 = np.stack([a * rng.uniform(0.3, 3, n), b * np.geomspace(0.05, 20, n)], axis=1)
    return y0, (x, y)


def _one_at_a_time(solver, y0, args, max_steps):
    """``optx.least_squares`` on each problem alone: values, Status codes, steps."""
    solve = eqx.filter_jit(lambda u, a: optx.least_squares(
        _saturation, solver, u, args=a, max_steps=max_steps, throw=False,
        options={"jac": "fwd"}))
    out = [solve(jnp.asarray(y0[i]), jax.tree_util.tree_map(lambda v, i=i: v[i], args))
           for i in range(len(y0))]
    return (np.stack([np.asarray(s.value) for s in out]),
            np.array([next(st for item, st in RESULT_STATUS if s.result == item) for s in out]),
            np.array([int(s.stats["num_steps"]) for s in out]))


def _same_status(name, status, steps, ref_status, ref_steps, max_steps) -> np.ndarray:
    """Assert the pooled and the single runs end in the same status; which problems may
    differ (returned): dogleg's trust-region decisions flip on rounding, so a problem
    that ends at the step cap in either run may have converged on its last step in the
    other."""
    edge = ((steps == max_steps) | (ref_steps == max_steps) if name == "dogleg"
            else np.zeros(len(steps), bool))
    np.testing.assert_array_equal(status[~edge], ref_status[~edge])
    assert set(status[edge]) | set(ref_status[edge]) <= {Status.CONVERGED, Status.MAX_STEPS}
    return edge


@pytest.mark.parametrize("name", SOLVERS)
def test_pooled_with_refills_equals_one_problem_at_a_time(name):
    y0, args = _problems()
    # 7 problems in 3 slots: slots are refilled while others are mid-solve
    value, status, steps = solve_pooled(SOLVERS[name], _saturation, y0, args, pool_size=3,
                                        max_steps=60)
    ref_value, ref_status, ref_steps = _one_at_a_time(SOLVERS[name], y0, args, 60)
    assert len(set(steps)) > 2  # problems finish at different times
    # the same iterations, batched: the same status, step counts and optimum. Dogleg's
    # trust-region decisions near the end flip on rounding (batched and single kernels
    # differ): its step counts differ for one or two problems (e.g. 30 / 18 against 22 /
    # 25), the optimum not
    edge = _same_status(name, status, steps, ref_status, ref_steps, 60)
    if name != "dogleg":
        np.testing.assert_array_equal(steps, ref_steps)
    np.testing.assert_allclose(value[~edge], ref_value[~edge], rtol=1e-6, atol=0)
    assert (status == Status.CONVERGED).sum() >= 5


@pytest.mark.parametrize("name", SOLVERS)
def test_failures_end_in_a_status_never_a_crash_or_nan(name):
    y0, (x, y) = _problems()
    y = y.copy()
    y[6, 3] = np.nan  # a non-finite residual from the first step
    max_steps = 8  # too few for the far starts
    value, status, steps = solve_pooled(SOLVERS[name], _saturation, y0, (x, y), pool_size=3,
                                        max_steps=max_steps)
    assert status[6] == Status.NONFINITE
    np.testing.assert_array_equal(value[6], y0[6])  # the start, not NaN
    assert np.all(np.isfinite(value))
    assert (status == Status.MAX_STEPS).sum() >= 1 and steps.max() == max_steps
    _, ref_status, ref_steps = _one_at_a_time(SOLVERS[name], y0, (x, y), max_steps)
    _same_status(name, status, steps, ref_status, ref_steps, max_steps)


def test_fit_trials_runs_optimistix_solvers_on_hard_cases():
    t, y, t_out, t_back = hard_cases()
    kw = dict(model="elastic_plastic", chunk_size=4, threads=1)
    by_name = fit_trials(y, t, (t_out, t_back), solver="optx-lm", **kw)
    by_object = fit_trials(y, t, (t_out, t_back),
                           solver=optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8), **kw)
    assert by_name.solver == by_object.solver == "optx-lm"
    np.testing.assert_array_equal(np.stack(by_name.u), np.stack(by_object.u))
    assert {Status(s) for s in by_name.status} <= set(Status)
    assert np.all(np.isfinite(np.stack(by_name.u)))
    assert (by_name.status == Status.CONVERGED).sum() >= 3


def test_fit_trials_refuses_a_minimiser():
    ts = known_truth("elastic_plastic", 1)
    with pytest.raises(FitError, match="optimistix least-squares solver, not BFGS"):
        fit_trials(ts.y, ts.t, (ts.t_out, ts.t_back), model="elastic_plastic",
                   solver=optx.BFGS(rtol=1e-8, atol=1e-8))


def test_threads_do_not_change_results():
    y0, args = _problems(8, seed=1)
    solver = SOLVERS["optx-lm"]
    one = solve_pooled(solver, _saturation, y0, args, pool_size=3, max_steps=60, threads=1)
    two = solve_pooled(solver, _saturation, y0, args, pool_size=3, max_steps=60, threads=2)
    for a, b in zip(one, two, strict=True):  # two pools of 3 slots, a thread each
        np.testing.assert_array_equal(a, b)


def test_compiler_options_reach_xla():
    """The host loop's options compile the pool's calls (same optimum, rounding aside); an
    option XLA does not know is refused, so the options are not silently dropped."""
    y0, args = _problems(5, seed=2)
    solver = SOLVERS["lm"]
    plain = solve_pooled(solver, _saturation, y0, args, pool_size=3, max_steps=60)
    host = solve_pooled(solver, _saturation, y0, args, pool_size=3, max_steps=60,
                        compiler_options=HOST_LOOP_COMPILER_OPTIONS)
    np.testing.assert_array_equal(host[1], plain[1])
    np.testing.assert_allclose(host[0], plain[0], rtol=1e-8)
    with pytest.raises(Exception, match="no_such_xla_option"):
        solve_pooled(solver, _saturation, y0, args, pool_size=3, max_steps=60,
                     compiler_options={"no_such_xla_option": 1})
