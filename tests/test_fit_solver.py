"""BatchedLevenbergMarquardt as an optimistix solver: one trial, in the pool driver, NIST StRD."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from scipy.optimize import least_squares

from frictionfit.errors import Status
from frictionfit.fit import Trials
from frictionfit.fit._guess import initial_guess
from frictionfit.fit._optx import solve_pooled
from frictionfit.fit._problem import Problem, residual_fn
from frictionfit.fit.solver import DATA_FTOL, DATA_RTOL, BatchedLevenbergMarquardt
from frictionfit.models import get_model
from frictionfit.simulation.trials import simulate_trials


def _relaxation_problems(seed: int):
    """Three simulated relaxation trials: starting points, their data and the residual."""
    model = get_model("relaxation")
    ts = simulate_trials("relaxation", 3, seed=seed)
    n = ts.y.shape[0]
    u0 = np.asarray(initial_guess(model, ts.t, ts.y, ts.t_out, ts.t_back, np.ones(n)))
    data = Problem.of(Trials.from_arrays(ts.y, ts.t, (ts.t_out, ts.t_back), direction=1.0), u0)
    return u0, data, residual_fn(model, tuple(range(model.n_params)))


def test_one_trial_through_optimistix_equals_the_pooled_fit():
    u0, data, residual = _relaxation_problems(seed=1)
    n = u0.shape[0]
    solver = BatchedLevenbergMarquardt(rtol=1e-8, atol=1e-10, ftol=1e-6)
    # 3 trials in 2 slots: the third is refilled into a slot mid-solve
    pooled, status, steps = solve_pooled(solver, residual, u0, data, pool_size=2,
                                         max_steps=200)
    for i in range(n):
        sol = optx.least_squares(residual, solver, jnp.asarray(u0[i]), args=_row(data, i),
                                 max_steps=200, throw=False)
        assert status[i] == Status.CONVERGED and sol.result == optx.RESULTS.successful
        assert int(sol.stats["steps"]) == steps[i]
        np.testing.assert_allclose(np.asarray(sol.value), pooled[i], rtol=1e-8, atol=1e-12)


def test_the_pool_returns_the_normal_matrix_at_each_solution():
    """``solver_stats``: the solver's ``J^T J`` at each pooled solution is the Jacobian's
    there (so nothing computes it again), also for a problem refilled into a slot."""
    import jax

    u0, data, residual = _relaxation_problems(seed=2)
    n, p = u0.shape
    u, status, _, stats = solve_pooled(BatchedLevenbergMarquardt(), residual, u0, data,
                                       pool_size=2, max_steps=200, solver_stats=True)
    assert stats["jtj"].shape == (n, p, p)
    for i in range(n):
        row = jax.tree_util.tree_map(jnp.asarray, _row(data, i))
        jac = np.asarray(jax.jacfwd(residual)(jnp.asarray(u[i]), row))
        np.testing.assert_allclose(stats["jtj"][i], jac.T @ jac, rtol=1e-9,
                                   atol=1e-9 * np.abs(jac.T @ jac).max())


def _row(data, i):
    import jax

    return jax.tree_util.tree_map(lambda a: a[i], data)


def _exp_rise(b, x):
    return b[0] * (1 - jnp.exp(-b[1] * x))


def _chwirut(b, x):
    return jnp.exp(-b[0] * x) / (b[1] + b[2] * x)


def _gauss(b, x):
    return (b[0] * jnp.exp(-b[1] * x) + b[2] * jnp.exp(-((x - b[3]) ** 2) / b[4] ** 2)
            + b[5] * jnp.exp(-((x - b[6]) ** 2) / b[7] ** 2))


def _rational3(b, x):
    return (b[0] + b[1] * x + b[2] * x**2 + b[3] * x**3) / (1 + b[4] * x + b[5] * x**2
                                                          + b[6] * x**3)


def _lanczos(b, x):
    return b[0] * jnp.exp(-b[1] * x) + b[2] * jnp.exp(-b[3] * x) + b[4] * jnp.exp(-b[5] * x)


def _enso(b, x):
    w = 2 * jnp.pi * x
    return (b[0] + b[1] * jnp.cos(w / 12) + b[2] * jnp.sin(w / 12) + b[4] * jnp.cos(w / b[3])
            + b[5] * jnp.sin(w / b[3]) + b[7] * jnp.cos(w / b[6]) + b[8] * jnp.sin(w / b[6]))


#: Every NIST StRD nonlinear regression model (``Models`` in the shared folder), by problem.
#: Nelson's response is ``log(y)`` and its predictor the pair ``(x1, x2)``.
NIST = {
    "Bennett5": lambda b, x: b[0] * (b[1] + x) ** (-1 / b[2]),
    "BoxBOD": _exp_rise,
    "Chwirut1": _chwirut,
    "Chwirut2": _chwirut,
    "DanWood": lambda b, x: b[0] * x ** b[1],
    "ENSO": _enso,
    "Eckerle4": lambda b, x: (b[0] / b[1]) * jnp.exp(-0.5 * ((x - b[2]) / b[1]) ** 2),
    "Gauss1": _gauss,
    "Gauss2": _gauss,
    "Gauss3": _gauss,
    "Hahn1": _rational3,
    "Kirby2": lambda b, x: (b[0] + b[1] * x + b[2] * x**2) / (1 + b[3] * x + b[4] * x**2),
    "Lanczos1": _lanczos,
    "Lanczos2": _lanczos,
    "Lanczos3": _lanczos,
    "MGH09": lambda b, x: b[0] * (x**2 + x * b[1]) / (x**2 + x * b[2] + b[3]),
    "MGH10": lambda b, x: b[0] * jnp.exp(b[1] / (x + b[2])),
    "MGH17": lambda b, x: b[0] + b[1] * jnp.exp(-x * b[3]) + b[2] * jnp.exp(-x * b[4]),
    "Misra1a": _exp_rise,
    "Misra1b": lambda b, x: b[0] * (1 - (1 + b[1] * x / 2) ** -2),
    "Misra1c": lambda b, x: b[0] * (1 - (1 + 2 * b[1] * x) ** -0.5),
    "Misra1d": lambda b, x: b[0] * b[1] * x / (1 + b[1] * x),
    "Nelson": lambda b, x: b[0] - b[1] * x[:, 0] * jnp.exp(-b[2] * x[:, 1]),
    "Rat42": lambda b, x: b[0] / (1 + jnp.exp(b[1] - b[2] * x)),
    "Rat43": lambda b, x: b[0] / (1 + jnp.exp(b[1] - b[2] * x)) ** (1 / b[3]),
    "Roszman1": lambda b, x: b[0] - b[1] * x - jnp.arctan(b[2] / (x - b[3])) / jnp.pi,
    "Thurber": _rational3,
}


def _read_nist(path):
    """Starting values (2, p), certified values (p,), certified residual sum of squares, and
    the data ``y, x`` (NIST's layout: parameters from line 41, data from line 61)."""
    lines = path.read_text().splitlines()
    params = [ln.split("=")[1].split() for ln in lines[40:60] if ln.strip().startswith("b")
              and "=" in ln]
    values = np.array(params, dtype=np.float64)
    rss = next(float(ln.split()[-1]) for ln in lines[40:60] if "Residual Sum of Squares" in ln)
    data = np.array([ln.split() for ln in lines[60:] if ln.strip()], dtype=np.float64)
    y, x = data[:, 0], data[:, 1] if data.shape[1] == 2 else data[:, 1:]
    if path.stem == "Nelson":
        y = np.log(y)
    return values[:, :2].T, values[:, 2], rss, y, x


def _digits(fit, certified):
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.min(-np.log10(np.abs(fit - certified) / np.abs(certified)))


@pytest.mark.parametrize("start", [0, 1], ids=["start1", "start2"])
@pytest.mark.parametrize("name", list(NIST))
def test_nist_strd_four_digits_or_an_honest_failure(shared, name, start):
    path = shared / "reference" / "nist-strd" / f"{name}.dat"
    if not path.exists():
        pytest.skip(f"{path.name} is not in ../shared (kept by the team for independent scoring)")
    starts, certified, rss, y, x = _read_nist(path)
    model = NIST[name]

    def fn(b, args):
        return model(b, args[1]) - args[0]

    # the model and the data as read reproduce NIST's residual sum of squares
    at_certified = float(np.sum(np.asarray(fn(jnp.asarray(certified), (y, x))) ** 2))
    assert at_certified == pytest.approx(rss, rel=1e-6), name
    b0 = starts[start]
    sol = optx.least_squares(fn, BatchedLevenbergMarquardt(),  # its default tolerances
                             jnp.asarray(b0), args=(jnp.asarray(y), jnp.asarray(x)),
                             max_steps=2000, throw=False)
    ours = _digits(np.asarray(sol.value), certified)
    if ours >= 4:
        return
    # Wrong digits only with a failure status, and only where scipy (MINPACK) fails too:
    # BoxBOD from start 1 reaches a plateau (b2 > 100, the exponential saturated; cost 8.4x
    # the certified one) that MINPACK calls converged and ours singular (b2 no longer acts).
    assert sol.result != optx.RESULTS.successful, (name, start, ours, sol.value)
    ref = least_squares(lambda b: np.asarray(fn(jnp.asarray(b), (y, x))), b0, method="lm",
                        xtol=1e-15, ftol=1e-15, max_nfev=20000)
    assert _digits(ref.x, certified) < 4, (name, start, "scipy gets it", ref.x)


@pytest.mark.parametrize("bounded", [False, True])
def test_a_parameter_that_no_longer_acts_is_reported_singular_unless_on_a_bound(bounded):
    x = jnp.linspace(1.0, 10.0, 20)

    def fn(b, y):  # b[1] saturates: past ~40 it does not change the residual at all
        return b[0] * (1 - jnp.exp(-b[1] * x)) - y

    y = 3.0 * (1 - jnp.exp(-0.8 * x))
    options = {"bounded": True} if bounded else {}
    stuck = optx.least_squares(fn, BatchedLevenbergMarquardt(), jnp.array([2.0, 60.0]), args=y,
                               options=options, throw=False)
    assert stuck.result == (optx.RESULTS.successful if bounded else optx.RESULTS.singular)
    solved = optx.least_squares(fn, BatchedLevenbergMarquardt(), jnp.array([2.0, 1.0]), args=y,
                                options=options, throw=False)
    assert solved.result == optx.RESULTS.successful
    np.testing.assert_allclose(np.asarray(solved.value), [3.0, 0.8], rtol=1e-8)


def test_fit_trials_takes_the_solver_object():
    from frictionfit.errors import FitError
    from frictionfit.fit import fit_trials

    ts = simulate_trials("elastic_plastic", 4, seed=2)
    args = (ts.y, ts.t, (ts.t_out, ts.t_back))
    by_name = fit_trials(*args, model="elastic_plastic", solver="lm")
    same = BatchedLevenbergMarquardt(rtol=DATA_RTOL, ftol=DATA_FTOL)  # fit_trials' tolerances
    by_object = fit_trials(*args, model="elastic_plastic", solver=same)
    np.testing.assert_array_equal(np.stack(by_name.u), np.stack(by_object.u))
    loose = fit_trials(*args, model="elastic_plastic",
                       solver=BatchedLevenbergMarquardt(ftol=1e-2, rtol=1e-2))
    assert loose.n_steps.sum() < by_name.n_steps.sum()
    with pytest.raises(FitError, match="or give an optimistix least-squares solver"):
        fit_trials(*args, model="elastic_plastic", solver="newton")
    with pytest.raises(FitError, match="ftol given beside a solver object"):
        fit_trials(*args, model="elastic_plastic", solver=same, ftol=1e-3)
