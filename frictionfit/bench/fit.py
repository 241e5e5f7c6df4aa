"""Benchmark of per-trial fitting: frictionfit's batched LM against the peers a user would pick.

Peers, measured in the same run, interleaved (:func:`frictionfit.bench.timing.alternate`),
on the same model, data and starting points (the data-driven guess, unconstrained
coordinates):

* ``scipy-numpy``: ``scipy.optimize.least_squares(method="lm")`` on a plain NumPy
  implementation of the model (:func:`numpy_predict`, a per-sample Python loop;
  finite-difference Jacobian), trial by trial;
* ``scipy-jax``: the same scipy solver driven by the jitted JAX residual and
  forward-mode Jacobian, trial by trial;
* for the solver paths (:func:`_solver_paths`), optimistix's own batch:
  ``jax.vmap(optx.least_squares)`` over chunks, in rounds (:func:`_vmapped_rounds`).

Errors are median relative errors of the true model's parameters
(``|est - true| / max(|true|, 0.05)``) over the parameters the trials identify
(:data:`IDENTIFIABLE`); ``median_rel_error_all`` includes the stiffness, movement
duration and slip-weakening length, which trade off (see :mod:`frictionfit.fit._stats`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from frictionfit.bench.timing import alternate, machine_info, timed
from frictionfit.errors import Status
from frictionfit.fit import Trials, fit_trials, initial_guess
from frictionfit.fit._problem import Problem, noise_scale
from frictionfit.models import FAMILY, ContactModel, get_model
from frictionfit.models.stick_slip import maxwell_branches
from frictionfit.simulation.trials import TrialSet, simulate_trials

__all__ = ["IDENTIFIABLE", "measure", "numpy_contact_force", "numpy_predict", "run"]

#: Parameters a 2-s, 20 dB trial identifies (the others trade off with each other).
IDENTIFIABLE = ("offset", "f_kin", "f_static_excess", "relax_frac", "tau", "delay",
                "relax_frac2", "tau2", "damping")
DEFAULT_MODEL = "relaxation"


def numpy_predict(model: ContactModel, u: np.ndarray, t: np.ndarray, t_out: float,
                  t_back: float, direction: float) -> np.ndarray:
    """Plain NumPy twin of ``model.predict`` (``drive="events"``): force (N) at times ``t`` (s)."""
    v = {p.name: p.to_physical(np.float64(u[i])) for i, p in enumerate(model.params)}

    def shape(s):
        return 0.5 - 0.5 * np.cos(np.pi * np.clip(s, 0.0, 1.0))

    x = model.stroke_mm * (shape((t - t_out - v["delay"]) / v["ramp"])
                           - shape((t - t_back - v["delay"]) / v["ramp"]))
    return v["offset"] + direction * numpy_contact_force(x, t[1] - t[0], v)


def numpy_contact_force(x: np.ndarray, dt, v: dict) -> np.ndarray:
    """Plain NumPy twin of :func:`~frictionfit.models.stick_slip.contact_force`: force (N)
    for the drive ``x`` (mm), a per-sample Python loop.

    ``dt``: one interval (s), or one per sample (``dt[0]`` any positive value); ``v``: the
    law's physical values by name, an effect whose parameter is absent left out.
    """
    get = v.get
    dt = np.broadcast_to(dt, x.shape)
    coef = []
    for frac, tau in zip(*maxwell_branches(get("relax_frac"), get("tau"), get("relax_frac2"),
                                           get("tau2")), strict=True):
        h = dt / tau
        g = np.where(h < 1e-8, 1.0 - 0.5 * h, -np.expm1(-h) / np.maximum(h, 1e-300))
        coef.append((frac, np.exp(-h), g))
    k, f_kin, excess = v["k"], v["f_kin"], get("f_static_excess")
    damping, wear = get("damping"), get("wear")
    if wear is not None:
        half_travel = 0.5 * np.sum(np.abs(np.diff(x)))
    z = s = travel = 0.0
    ws = [0.0] * len(coef)
    x_old, direction_of_motion = x[0], 1.0
    force = np.empty_like(x)
    for n, x_new in enumerate(x):
        dx = x_new - x_old
        new_dir = np.sign(dx) if dx != 0.0 else direction_of_motion
        limit = f_kin
        if wear is not None:
            travel += abs(dx)
            limit = f_kin * np.exp(wear * (half_travel - travel))
        if excess is not None:
            if dx != 0.0 and new_dir != direction_of_motion:
                s = 0.0
            limit = limit + excess * np.exp(-s * (1.0 / v["slip_length"]))
        z_max = limit * (1.0 / k)
        z_trial = z + dx
        z_new = min(max(z_trial, -z_max), z_max)
        if excess is not None:
            s = s + abs(z_trial - z_new)
        ws = [z_new + a[n] * (w - z) - (z_new - z) * g[n]
              for w, (_, a, g) in zip(ws, coef, strict=True)]
        f = k * (z_new - sum(frac * w for w, (frac, _, _) in zip(ws, coef, strict=True)))
        if damping is not None:
            f = f + damping * (z_new - z) / dt[n]
        force[n] = f
        z, x_old, direction_of_motion = z_new, x_new, new_dir
    return force


def _rel_errors(model: ContactModel, u: np.ndarray, ts: TrialSet) -> dict[str, np.ndarray]:
    """Per parameter, the relative error of each trial's estimate against the truth."""
    out = {}
    for j, p in enumerate(model.params):
        est = p.to_physical(np.asarray(u[:, j], dtype=np.float64))
        true = ts.truth[p.name]
        out[p.name] = np.abs(est - true) / np.maximum(np.abs(true), 0.05)
    return out


def _median_error(errors: dict[str, np.ndarray], ok: np.ndarray, names) -> float:
    """Median over trials ``ok`` and the parameters ``names`` of the relative errors."""
    vals = [errors[n][ok] for n in names if n in errors]
    flat = np.concatenate(vals) if vals else np.array([])
    flat = flat[np.isfinite(flat)]
    return float(np.median(flat)) if flat.size else float("nan")


def _scipy_fits(model, ts, u0, residual, jac):
    """``scipy.optimize.least_squares(method="lm")`` trial by trial; (u, success). Variables
    scaled by the Jacobian's columns (``x_scale="jac"``, MINPACK's and scipy's default since
    1.16): on 16 relaxation trials the same median error as ours (0.0098), with unit scales
    0.0108 (the whole-measurement peers take unit scales: there they converge more often)."""
    from scipy.optimize import least_squares

    u = np.empty_like(u0)
    ok = np.zeros(len(u0), dtype=bool)
    for i in range(len(u0)):
        kw = {} if jac is None else {"jac": lambda x, i=i: jac(x, i)}
        sol = least_squares(lambda x, i=i: residual(x, i), u0[i], method="lm", x_scale="jac",
                            **kw)
        u[i], ok[i] = sol.x, sol.success
    return u, ok


def _peers(model: ContactModel, ts: TrialSet, u0: np.ndarray):
    """The two scipy peers as zero-argument callables returning ``(u, success)``."""
    import jax
    import jax.numpy as jnp

    t = ts.t
    tj = jnp.asarray(t)
    noise = noise_scale(ts.y, np.isfinite(ts.y))

    def np_resid(x, i):  # the same objective as ours: data residuals, then prior rows
        data = numpy_predict(model, x, t, ts.t_out, ts.t_back, ts.direction[i]) - ts.y[i]
        return np.concatenate([data, noise[i] * model.prior_residuals(np.asarray(x))])

    def jax_resid(x, y, d, s):
        data = model.predict(x, tj, (ts.t_out, ts.t_back), d) - y
        return jnp.concatenate([data, s * model.prior_residuals(x)])

    jres = jax.jit(jax_resid)
    jjac = jax.jit(jax.jacfwd(jax_resid))

    def j_resid(x, i):
        return np.asarray(jres(x, ts.y[i], ts.direction[i], noise[i]))

    def j_jac(x, i):
        return np.asarray(jjac(x, ts.y[i], ts.direction[i], noise[i]))

    return (lambda: _scipy_fits(model, ts, u0, np_resid, None),
            lambda: _scipy_fits(model, ts, u0, j_resid, j_jac))


def _trials(ts: TrialSet) -> Trials:
    """The simulated trials as every fit takes them, with their true channel signs."""
    return Trials.from_arrays(ts.y, ts.t, (ts.t_out, ts.t_back), direction=ts.direction)


def _ours(ts: TrialSet, model: str, **kw):
    trials = _trials(ts)

    def call():
        res = fit_trials(trials, model=model, **kw)
        flagged = {n: np.array([n in f for f in res.flags]) for n in res.values}
        return np.stack(res.u), res.status == Status.CONVERGED, flagged

    return call


def _point(config, seconds, n, model, u_ok, ts) -> dict:
    u, ok = u_ok[:2]
    errors = _rel_errors(model, u, ts)
    return {"config": config, "seconds_per_trial": seconds / n,
            "error": _median_error(errors, ok, IDENTIFIABLE),
            "error_name": "median rel. param error", "success_rate": float(np.mean(ok))}


def run(*, quick: bool = False, seed: int = 0) -> dict:
    """Measure fitting throughput and accuracy against the scipy peers (see module doc).

    The full run fits 256 trials of the default model (``relaxation``: 2-s
    single-channel trials at 1 kHz, 20 dB) with pools of 32, and 8 trials with each
    peer (the NumPy peer takes seconds per trial); then a grid of configurations.
    ``quick=True`` fits 64 ``elastic_plastic`` trials in pools of 32 (a batch big
    enough for batching to count: with 4 trials in a pool of 4 the comparison with
    scipy-jax measured per-call overhead, 1.1x) and 4 per peer, without the grid;
    under a minute on this machine. ``summary["measurements"]``: truth recovery and
    speed of whole-measurement fits (:func:`frictionfit.bench.measurement.recovery`; 140
    measurements: every class in four sessions; 8 with ``quick``), with its scipy
    peers on 16 of them (:data:`~frictionfit.bench.measurement.PEER_N`; all 8 with ``quick``;
    ``scipy-numpy`` on 2). Timings are medians of interleaved
    repetitions; ``compile_s`` is the first call of ours minus a steady one. The full run
    adds ``summary["measurements_motor_reads"]``: the same measurements with the motor's
    position read at 50 Hz, each movement's timing taken from the reads (no peers).
    ``summary["rigs"]``: the recovery on each simulated rig of :data:`BENCH_RIGS` (35
    measurements each, one session of every class; 8 with ``quick``; no peers): the
    material's parameters through each rig's stroke, motor, finger and sensors.
    """
    from frictionfit.bench.measurement import RECOVERY_N, recovery

    if quick:
        out = measure("elastic_plastic", 64, 4, 32, 1, grid=False, seed=seed)
    else:
        out = measure(DEFAULT_MODEL, 256, 8, 32, 2, grid=True, seed=seed)
    n = 8 if quick else RECOVERY_N
    out["summary"]["measurements"] = recovery(n, seed=seed)
    if not quick:
        out["summary"]["measurements_motor_reads"] = recovery(n, seed=seed, n_peer=0,
                                                              position_rate_hz=50.0)
    out["summary"]["rigs"] = rig_recovery(8 if quick else 35, seed)
    return out


#: The simulated rigs ``bench fit`` scores the recovery on.
BENCH_RIGS = ("sim-a", "sim-b", "sim-c")


def rig_recovery(n: int, seed: int = 0, rigs: tuple[str, ...] = BENCH_RIGS) -> dict:
    """Per simulated rig: :func:`~frictionfit.bench.measurement.recovery` of ``n``
    measurements made on it (no peers)."""
    from frictionfit.bench.measurement import recovery
    from frictionfit.simulation.rigs import rig_for

    return {name: recovery(n, seed=seed, n_peer=0, rig=rig_for(name)) for name in rigs}


def measure(name: str, n: int, n_peer: int, pool: int, reps: int, *, grid: bool,
            seed: int = 0) -> dict:
    """:func:`run` at a chosen size: ``n`` trials of ``name`` (pools of ``pool``),
    ``n_peer`` per peer, ``reps`` interleaved repetitions, the config grid or not."""
    ts = simulate_trials(name, n, seed=seed)
    model = get_model(name)
    times = (np.full(n, ts.t_out), np.full(n, ts.t_back))
    u0 = initial_guess(model, ts.t, ts.y, *times, ts.direction)
    peer_ts = TrialSet(name, ts.t, ts.y[:n_peer], ts.t_out, ts.t_back, ts.direction[:n_peer],
                       {k: v[:n_peer] for k, v in ts.truth.items()}, ts.noise_sd[:n_peer])
    numpy_peer, jax_peer = _peers(model, peer_ts, u0[:n_peer])
    calls = {"ours": _ours(ts, name, chunk_size=pool, u0=u0),
             "ours-peer-set": _ours(peer_ts, name, chunk_size=pool, u0=u0[:n_peer]),
             "scipy-numpy": numpy_peer, "scipy-jax": jax_peer}
    first_s, _ = timed(calls["ours"])
    timed(calls["ours-peer-set"])
    timed(jax_peer)  # jit compile of the peer's residual and Jacobian
    runs = alternate(calls, repeats=reps, warmup=False)
    sizes = {k: n if k == "ours" else n_peer for k in runs}
    sets = {k: ts if k == "ours" else peer_ts for k in runs}
    per_trial = {k: runs[k]["median_s"] / sizes[k] for k in runs}
    errs = {k: _rel_errors(model, runs[k]["result"][0], sets[k]) for k in runs}
    oks = {k: runs[k]["result"][1] for k in runs}
    points = [_point(f"{k} {name} float64", runs[k]["median_s"], sizes[k], model,
                     runs[k]["result"], sets[k]) for k in runs]
    paths = {}
    if grid:
        points += _configs(seed, pool)
        points += _solve_configs(seed, pool)
        path_points, paths = _solver_paths(ts, model, u0, pool)
        points += path_points
    summary = {
        "model": name, "n_trials": n, "n_trials_peers": n_peer,
        "trials_per_s": 1.0 / per_trial["ours"],
        "speedup_vs_scipy_numpy": per_trial["scipy-numpy"] / per_trial["ours"],
        "speedup_vs_scipy_jax": per_trial["scipy-jax"] / per_trial["ours"],
        "median_rel_error": _median_error(errs["ours"], oks["ours"], IDENTIFIABLE),
        "median_rel_error_all": _median_error(errs["ours"], oks["ours"], model.param_names),
        "median_rel_error_by_param": {
            k: _median_error(errs["ours"], oks["ours"], [k]) for k in model.param_names},
        "median_rel_error_peer_set": _median_error(
            errs["ours-peer-set"], oks["ours-peer-set"], IDENTIFIABLE),
        "scipy_median_rel_error": _median_error(
            errs["scipy-numpy"], oks["scipy-numpy"], IDENTIFIABLE),
        "scipy_jax_median_rel_error": _median_error(
            errs["scipy-jax"], oks["scipy-jax"], IDENTIFIABLE),
        "flagged_rate_by_param": {
            k: float(np.mean(v)) for k, v in runs["ours"]["result"][2].items()},
        "success_rate": float(np.mean(oks["ours"])),
        "success_rate_peer_set": float(np.mean(oks["ours-peer-set"])),
        "scipy_success_rate": float(np.mean(oks["scipy-numpy"])),
        "scipy_jax_success_rate": float(np.mean(oks["scipy-jax"])),
        "compile_s": float(max(first_s - runs["ours"]["median_s"], 0.0)),
        "load_average": _load(),
        **paths,
    }
    return {"stage": "fit", "summary": summary, "points": points, "machine": machine_info()}


def _configs(seed: int, pool: int) -> list[dict]:
    """Speed/error points over family members, solvers, tolerances and pool sizes."""
    n = 64
    grid = [(m.name, "lm", 1e-6, pool) for m in FAMILY]
    grid += [(DEFAULT_MODEL, "lm", 1e-4, pool), (DEFAULT_MODEL, "lm", 1e-8, pool),
             (DEFAULT_MODEL, "lm", 1e-6, pool * 4),
             (DEFAULT_MODEL, "optx-lm", 1e-6, 32), (DEFAULT_MODEL, "dogleg", 1e-6, 32),
             (DEFAULT_MODEL, "gauss-newton", 1e-6, 32)]
    points = []
    for name, solver, ftol, chunk in grid:
        ts = simulate_trials(name, n, seed=seed + 1)
        call = _ours(ts, name, solver=solver, ftol=ftol, chunk_size=min(chunk, n))
        timed(call)  # compile
        seconds, result = timed(call)
        points.append(_point(f"{solver} {name} ftol={ftol:g} chunk={min(chunk, n)} float64",
                             seconds, n, get_model(name), result, ts))
    return points


def _solve_configs(seed: int, pool: int, n: int = 128, reps: int = 3) -> list[dict]:
    """The LM solve alone (no statistics) in float64 and float32, with 1 and 2 host threads.

    Alternated, median of ``reps``; the data-driven start, the default model, pools
    of ``n // 4`` (at most ``pool``) so that each of two threads has full pools. float32
    runs the same code on float32 data (frictionfit's default stays float64); a
    trial counts as a success when it converged with finite parameters.
    """
    import jax

    from frictionfit.fit._optx import solve_pooled
    from frictionfit.fit._problem import residual_fn
    from frictionfit.fit.solver import DATA_FTOL, DATA_RTOL, BatchedLevenbergMarquardt

    ts = simulate_trials(DEFAULT_MODEL, n, seed=seed + 2)
    model = get_model(DEFAULT_MODEL)
    trials = _trials(ts)
    u0 = initial_guess(model, ts.t, ts.y, *trials.drive_input, ts.direction)
    free = tuple(range(model.n_params))
    chunk = max(min(pool, n // 4), 4)  # two threads each get two full pools
    problem = Problem.of(trials, u0)

    def call(dtype, threads):
        data = jax.tree_util.tree_map(lambda a: a.astype(dtype) if a.dtype.kind == "f" else a,
                                      problem)

        def solve():
            solver = BatchedLevenbergMarquardt(rtol=DATA_RTOL, ftol=DATA_FTOL)
            u, status, _ = solve_pooled(solver, residual_fn(model, free),
                                        u0.astype(dtype), data, pool_size=chunk,
                                        max_steps=100, threads=threads)
            ok = (status == Status.CONVERGED) & np.all(np.isfinite(u), axis=1)
            return u.astype(np.float64), ok

        return solve

    calls = {f"lm-solve {DEFAULT_MODEL} {name} threads={th}": call(dtype, th)
             for name, dtype in (("float64", np.float64), ("float32", np.float32))
             for th in (1, 2)}
    runs = alternate(calls, repeats=reps, warmup=True)
    return [dict(_point(name, r["median_s"], n, model, r["result"], ts),
                 compile_s=max(r["warmup_s"] - r["median_s"], 0.0), load_average=_load())
            for name, r in runs.items()]


def _load() -> float | None:
    """The 1-minute load average (timings on a shared machine are noisy), where known."""
    import os

    try:
        return float(os.getloadavg()[0])
    except OSError:
        return None


def _solver_paths(ts: TrialSet, model: ContactModel, u0: np.ndarray, pool: int,
                  reps: int = 3) -> tuple[list[dict], dict]:
    """The solve alone (no statistics) of ``ts`` through each solver path, one host thread.

    frictionfit's LM (:class:`~frictionfit.fit.BatchedLevenbergMarquardt`) through the
    refilling driver (``solve_pooled``); optimistix's ``LevenbergMarquardt`` through the
    driver and vmapped in rounds (:func:`_vmapped_rounds`). Pools and chunks of
    ``pool``, the data-driven start, the tolerances ``fit_trials`` uses. Alternated,
    median of ``reps``, compile apart. Returns the points and summary numbers: trials/s
    per path and the ratios.
    """
    import optimistix as optx

    from frictionfit.fit._optx import solve_pooled
    from frictionfit.fit._problem import residual_fn
    from frictionfit.fit.solver import DATA_FTOL, DATA_RTOL, BatchedLevenbergMarquardt

    n, free = len(u0), tuple(range(model.n_params))
    data = Problem.of(_trials(ts), u0)

    def pooled(solver):
        def call():
            u, status, _ = solve_pooled(solver, residual_fn(model, free), u0, data,
                                        pool_size=pool, max_steps=100)
            return u, status == Status.CONVERGED
        return call

    def rounds():
        return _vmapped_rounds(model, free, u0, data, optx.LevenbergMarquardt(rtol=1e-8,
                                                                             atol=1e-8), pool)

    calls = {"lm driver": pooled(BatchedLevenbergMarquardt(rtol=DATA_RTOL, ftol=DATA_FTOL)),
             "optx-lm driver": pooled(optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8)),
             "optx-lm rounds": rounds}
    runs = alternate(calls, repeats=reps, warmup=True)
    points = [dict(_point(f"{k} {model.name} threads=1", r["median_s"], n, model,
                          r["result"], ts), compile_s=max(r["warmup_s"] - r["median_s"], 0.0))
              for k, r in runs.items()]
    rate = {k: n / r["median_s"] for k, r in runs.items()}
    summary = {}
    for k, r in runs.items():
        key = k.replace(" ", "_").replace("-", "_")
        summary[f"{key}_trials_per_s"] = rate[k]
        summary[f"{key}_success_rate"] = float(np.mean(r["result"][1]))
    summary["optx_lm_driver_over_rounds"] = rate["optx-lm driver"] / rate["optx-lm rounds"]
    return points, summary


@lru_cache(maxsize=8)
def _vmapped_solve(model: ContactModel, free: tuple[int, ...], solver, steps: int):
    """Jitted ``jax.vmap`` of ``optx.least_squares`` for ``steps`` steps: ``(u, ok, steps)``."""
    import equinox as eqx
    import jax
    import optimistix as optx

    from frictionfit.fit._problem import residual_fn

    def one(u0, data):
        sol = optx.least_squares(residual_fn(model, free), solver, u0, args=data,
                                 max_steps=steps, throw=False, options={"jac": "fwd"})
        return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]

    return eqx.filter_jit(jax.vmap(one))


def _vmapped_rounds(model: ContactModel, free: tuple[int, ...], u0: np.ndarray, data, solver,
                    chunk: int, max_steps: int = 100, steps_per_round: int = 40):
    """The plain optimistix batch: ``jax.vmap(optx.least_squares)`` over chunks of trials,
    whose while-loop runs every trial of a chunk until the slowest finishes, in rounds of
    ``steps_per_round`` steps; after a round, the unconverged trials are re-batched
    (padded to ``chunk``) and restarted where they stopped. ``(u, converged)``."""
    import jax
    import jax.numpy as jnp

    from frictionfit.fit._numerics import pad_rows

    solve = _vmapped_solve(model, free, solver, min(steps_per_round, max_steps))
    u, converged = u0.copy(), np.zeros(len(u0), dtype=bool)
    steps, active = np.zeros(len(u0), dtype=np.int64), np.arange(len(u0))
    while active.size:
        for start in range(0, active.size, chunk):
            idx = active[start:start + chunk]
            rows = pad_rows(idx, chunk)
            u_new, ok, taken = solve(jnp.asarray(u[rows]), jax.tree_util.tree_map(
                lambda a, r=rows: jnp.asarray(a[r]), data))
            u[idx], converged[idx] = np.asarray(u_new)[: idx.size], np.asarray(ok)[: idx.size]
            steps[idx] += np.asarray(taken)[: idx.size]
        active = active[~converged[active] & (steps[active] < max_steps)
                        & np.all(np.isfinite(u[active]), axis=1)]
    return u, converged
